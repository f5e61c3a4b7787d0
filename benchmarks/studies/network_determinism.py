"""Where Table 7's trained networks move: the same training under other CPU kernels and thread counts.

Trains one network per loss (:func:`sdm.network.train_network`, a small set: ``--configs`` training
configurations of the default synthetic Sky data, ``--epochs`` epochs) in a fresh process for each setting:

  * ``ATEN_CPU_CAPABILITY`` (torch's CPU kernels: ``default``, ``avx2``, ``avx512``; a machine runs the best its
    processor has unless told), set before torch is imported;
  * the thread count (``torch.set_num_threads``).

Prints, per loss, each setting's largest difference of the predicted shifts (metres) and of the weights from the
first setting's (the reference), and whether a second run of the reference gave the same bits. A setting the
processor lacks is reported as such by torch (it falls back) and shown.

    python benchmarks/studies/network_determinism.py [--configs 256] [--epochs 3] [--losses sdm_recommended silhouette]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: One training in its own process: argv = out.pt configs epochs threads losses...
TRAIN = """
import sys, torch
from sdm.batch import ConfigurationSet
from sdm.data import build_sky_dataset
from sdm.data.synthetic import synthetic_images
from sdm.network import NetworkSettings, mixed_levels, predict, shift_set, train_network

out, configs, epochs, threads, mkldnn, *losses = sys.argv[1:]
configs, epochs = int(configs), int(epochs)
torch.backends.mkldnn.enabled = mkldnn == "on"
torch.set_num_threads(int(threads))
built = build_sky_dataset(synthetic_images(2 * configs, seed=0), n_sample=configs + 80, seed=0, progress=False)
data = ConfigurationSet.from_configurations([c for c in built if c.num_points][: configs + 64])
whole = shift_set(data, 0, mixed_levels(len(data), (0, 1, 2, 3, 4), seed=1))
train, dev = whole.subset(range(configs)), whole.subset(range(configs, len(data)))
settings = NetworkSettings(epochs=epochs, batch_size=16, s=2, max_points=256)
saved = {"capability": torch.backends.cpu.get_cpu_capability()}
for loss in losses:
    net = train_network(loss, train, dev, settings).net
    saved[loss] = {"theta": predict(net, dev.data), "weights": torch.cat([p.detach().flatten() for p in net.parameters()])}
torch.save(saved, out)
"""


def run(out: Path, configs: int, epochs: int, threads: int, losses: list[str], capability: str | None,
        onednn: str | None, mkldnn: bool) -> dict:
    import torch

    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])),
                        "OMP_NUM_THREADS": str(threads)}
    for name, value in (("ATEN_CPU_CAPABILITY", capability), ("ONEDNN_MAX_CPU_ISA", onednn)):
        env.pop(name, None)
        if value:
            env[name] = value
    done = subprocess.run([sys.executable, "-c", TRAIN, str(out), str(configs), str(epochs), str(threads),
                           "on" if mkldnn else "off", *losses],
                          env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(done.stderr[-3000:])
    return torch.load(out)


def step_time(repeats: int = 40) -> None:
    """CPU ms of one ShiftNet step (batch 16, forward and backward, one thread), oneDNN on and off, alternated."""
    import time

    import torch

    from sdm.network import ShiftNet

    torch.set_num_threads(1)
    torch.manual_seed(0)
    net, images = ShiftNet(), torch.rand(16, 2, 128, 256)
    for enabled in (True, False, True, False):
        torch.backends.mkldnn.enabled = enabled
        began = time.process_time()
        for _ in range(repeats):
            net.zero_grad()
            net(images).sum().backward()
        print(f"ShiftNet step, oneDNN {'on' if enabled else 'off'}: "
              f"{1000 * (time.process_time() - began) / repeats:.1f} ms CPU (the mean of {repeats} steps)")


def main() -> None:
    import torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=int, default=256)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--losses", nargs="+", default=["sdm_recommended", "silhouette", "chamfer", "supervised"])
    parser.add_argument("--pinned", action="store_true", help="also each machine with torch's oneDNN kernels off")
    parser.add_argument("--step-time", action="store_true",
                        help="only time a ShiftNet step (batch of 16, forward and backward, one thread) with oneDNN "
                             "on and off")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    if args.step_time:
        step_time()
        return
    # (label, ATEN_CPU_CAPABILITY, ONEDNN_MAX_CPU_ISA, threads, oneDNN on): the processors a machine may have are
    # stood in for by capping torch's kernels and oneDNN's instruction set
    machines = [("this machine's kernels", None, None), ("AVX2 kernels", "avx2", "AVX2"),
                ("no vector kernels", "default", "SSE41")]
    settings = [(f"{name}, 1 thread", cap, isa, 1, True) for name, cap, isa in machines]
    settings += [("this machine's kernels, again", None, None, 1, True), ("this machine's kernels, 2 threads", None, None, 2, True)]
    if args.pinned:
        settings += [(f"{name}, 1 thread, oneDNN off", cap, isa, 1, False) for name, cap, isa in machines]
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        results = [run(Path(folder) / f"{i}.pt", args.configs, args.epochs, threads, args.losses, capability, isa, on)
                   for i, (_, capability, isa, threads, on) in enumerate(settings)]
    reference = results[0]
    print(f"{args.configs} training configurations, {args.epochs} epochs; differences from the reference "
          f"(kernels {reference['capability']}), metres for the shifts:")
    for (label, *_), result in zip(settings, results):
        for loss in args.losses:
            theta = float((result[loss]["theta"] - reference[loss]["theta"]).abs().max())
            weights = float((result[loss]["weights"] - reference[loss]["weights"]).abs().max())
            rows.append({"setting": label, "kernels": result["capability"], "loss": loss, "max_theta_diff_m": theta,
                         "max_weight_diff": weights})
            print(f"  {label:<50} (runs {result['capability']:>7}) {loss:>16}: shifts {theta:.3g} m, "
                  f"weights {weights:.3g}")
    print("settings that give the same bits (shifts and weights), per loss:")
    for loss in args.losses:
        groups: list[list[str]] = []
        firsts: list[dict] = []
        for (label, *_), result in zip(settings, results):
            for group, first in zip(groups, firsts):
                if all(torch.equal(result[loss][key], first[key]) for key in ("theta", "weights")):
                    group.append(label)
                    break
            else:
                groups.append([label]), firsts.append(result[loss])
        for number, group in enumerate(groups, start=1):
            print(f"  {loss:>16} #{number}: " + "; ".join(group))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
