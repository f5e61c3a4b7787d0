"""Where Table 7's trained networks move: the same training under other CPU kernels and thread counts.

Trains one network per loss (:func:`sdm.experiments.network.train_network`, a small set: ``--configs`` training
configurations of the default synthetic Sky data, ``--epochs`` epochs) in a fresh process for each setting:

  * ``ATEN_CPU_CAPABILITY`` (torch's CPU kernels: ``default``, ``avx2``, ``avx512``; a machine runs the best its
    processor has unless told), set before torch is imported;
  * the thread count (``torch.set_num_threads``).

Prints, per loss, each setting's largest difference of the predicted shifts (metres) and of the weights from the
first setting's (the reference), and whether a second run of the reference gave the same bits. A setting the
processor lacks is reported as such by torch (it falls back) and shown.

    python benchmarks/studies/network_determinism.py [--configs 256] [--epochs 3] [--losses sdm_closed_centred_r1 silhouette]

``--table7 SKY`` measures what those bits become in Table 7: the networks of config.yaml's ``research.network``
(its sizes, seed and training; training run 0) trained from the Sky file ``SKY`` under each setting, and each
network's mean distance on the test set per noise level, beside the reference's: how far a network's Table 7 row
moves from one processor to another, to set beside the spread of its training runs (Table 7's sd).

    python benchmarks/studies/network_determinism.py --table7 results/sky/sky.bin [--losses sdm_closed_centred_r1 silhouette]
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
from sdm.experiments.data import build_sky_dataset
from sdm.experiments.data.synthetic import synthetic_images
from sdm.experiments.network import NetworkSettings, mixed_noise_levels, predict, shift_set, train_network

out, configs, epochs, threads, mkldnn, *losses = sys.argv[1:]
configs, epochs = int(configs), int(epochs)
torch.backends.mkldnn.enabled = mkldnn == "on"
torch.set_num_threads(int(threads))
built = build_sky_dataset(synthetic_images(2 * configs, seed=0), n_sample=configs + 80, seed=0, progress=False)
data = ConfigurationSet.from_configurations([c for c in built if c.num_points][: configs + 64])
whole = shift_set(data, 0, mixed_noise_levels(len(data), (0, 1, 2, 3, 4), seed=1))
train, dev = whole.subset(range(configs)), whole.subset(range(configs, len(data)))
settings = NetworkSettings(epochs=epochs, batch_size=16, s=2, max_points=256)
saved = {"capability": torch.backends.cpu.get_cpu_capability()}
for loss in losses:
    net = train_network(loss, train, dev, settings).net
    saved[loss] = {"theta": predict(net, dev.data), "weights": torch.cat([p.detach().flatten() for p in net.parameters()])}
torch.save(saved, out)
"""


#: One Table 7 training in its own process: argv = out.pt sky threads losses...; config.yaml's research.network.
TABLE7 = """
import sys, torch, yaml
from sdm.experiments.network import distances, network_settings, predict, read_sets, train_network, training_seed
from sdm.sharing import TruthDistribution

out, sky, threads, *losses = sys.argv[1:]
torch.set_num_threads(int(threads))
network = yaml.safe_load(open("config.yaml"))["research"]["network"]
data = [network[key] for key in ("sizes", "seed", "levels", "camera_sd")]
seed = training_seed(network["seed"], 0)
sets = read_sets(sky, *data, train_noise=seed)
tests = {level: read_sets(sky, *data, parts=["test"], test_level=level)["test"] for level in network["noise_levels"]}
saved = {"capability": torch.backends.cpu.get_cpu_capability()}
for loss in losses:
    trained = train_network(loss, sets["train"], sets["dev"], network_settings(network["train"], seed),
                            prior=TruthDistribution(camera_sd=network["camera_sd"]))
    saved[loss] = {level: float(distances(predict(trained.net, test.data), test.truth).mean())
                   for level, test in tests.items()}
    saved[loss]["cpu_s"] = trained.seconds
torch.save(saved, out)
"""


def run(out: Path, configs: int, epochs: int, threads: int, losses: list[str], capability: str | None,
        onednn: str | None, mkldnn: bool, table7: str | None = None) -> dict:
    import torch

    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")])),
                        "OMP_NUM_THREADS": str(threads)}
    for name, value in (("ATEN_CPU_CAPABILITY", capability), ("ONEDNN_MAX_CPU_ISA", onednn)):
        env.pop(name, None)
        if value:
            env[name] = value
    command = ([sys.executable, "-c", TABLE7, str(out), table7, str(threads), *losses] if table7 else
               [sys.executable, "-c", TRAIN, str(out), str(configs), str(epochs), str(threads),
                "on" if mkldnn else "off", *losses])
    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=ROOT)
    if done.returncode:
        raise SystemExit(done.stderr[-3000:])
    return torch.load(out)


def step_time(repeats: int = 40) -> None:
    """CPU ms of one ShiftNet step (batch 16, forward and backward, one thread), oneDNN on and off, alternated."""
    import time

    import torch

    from sdm.experiments.network import ShiftNet

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


def table7_moves(sky: str, losses: list[str]) -> None:
    """Table 7's networks (training run 0) under this machine's kernels, AVX2's, no vector kernels and two threads:
    each network's test-set mean distance per level, and its difference from this machine's, in 1e-3 m."""
    settings = [("this machine's kernels, 1 thread", None, None, 1), ("AVX2 kernels, 1 thread", "avx2", "AVX2", 1),
                ("no vector kernels, 1 thread", "default", "SSE41", 1),
                ("this machine's kernels, 2 threads", None, None, 2)]
    with tempfile.TemporaryDirectory() as folder:
        results = [run(Path(folder) / f"{i}.pt", 0, 0, threads, losses, capability, isa, True, table7=sky)
                   for i, (_, capability, isa, threads) in enumerate(settings)]
    reference = results[0]
    noise_levels = [key for key in reference[losses[0]] if key != "cpu_s"]
    print(f"Table 7's networks (config.yaml, training run 0): test-set mean distance per noise level {noise_levels}, "
          f"1e-3 m; in brackets the difference from the first setting's")
    for loss in losses:
        for (label, *_), result in zip(settings, results):
            cells = ", ".join(f"{1e3 * result[loss][noise_level]:.1f} "
                              f"({1e3 * (result[loss][noise_level] - reference[loss][noise_level]):+.1f})" for noise_level in noise_levels)
            print(f"  {loss:>16}  {label:<36} (runs {result['capability']:>7}, {result[loss]['cpu_s']:.0f} CPU s): "
                  f"{cells}")


def main() -> None:
    import torch

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", type=int, default=256)
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--losses", nargs="+", default=["sdm_closed_centred_r1", "silhouette", "chamfer", "supervised"])
    parser.add_argument("--pinned", action="store_true", help="also each machine with torch's oneDNN kernels off")
    parser.add_argument("--step-time", action="store_true",
                        help="only time a ShiftNet step (batch of 16, forward and backward, one thread) with oneDNN "
                             "on and off")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--table7", metavar="SKY", help="Table 7's networks (config.yaml) under each setting, from SKY")
    args = parser.parse_args()
    if args.step_time:
        step_time()
        return
    if args.table7:
        table7_moves(args.table7, args.losses if args.losses != parser.get_default("losses")
                     else ["sdm_closed_centred_r1", "silhouette"])
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
