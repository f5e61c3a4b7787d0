"""The SDM layer under ``torch.compile``: graph breaks and time per forward + backward, against eager.

Prints, in one run on one CPU thread, for the layer's loss at zoom 1 on a batch of 8 small configurations
(``tests/scenes.py``) as a function of the shift theta: the graphs and graph breaks Dynamo makes and why
(``torch._dynamo.explain``), then ms per forward + backward eager, compiled with ``backend="eager"`` and
with the default inductor backend (and its first, compiling call). Ratios are measured in the same run;
the absolute figures are for reading.

    python benchmarks/speed/bench_compile.py [--steps 200]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from scenes import configuration_set  # noqa: E402

from sdm.mapping import SpatialDomainMapping  # noqa: E402
from sdm.sky import shift_vector  # noqa: E402


def loss_of_theta():
    batch = configuration_set(8, seed=2).batch(range(8))
    layer = SpatialDomainMapping(s=4, zoom=1)

    def loss_of(theta):
        return layer(batch.points + shift_vector(theta, batch.points), batch.pixels, batch.targets,
                     batch.config, batch.rank).loss

    return loss_of


def ms_per_step(function, theta: torch.Tensor, steps: int) -> float:
    for _ in range(10):
        function(theta.detach().clone().requires_grad_(True)).backward()
    start = time.perf_counter()
    for _ in range(steps):
        function(theta.detach().clone().requires_grad_(True)).backward()
    return (time.perf_counter() - start) / steps * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200)
    args = parser.parse_args()
    torch.set_num_threads(1)
    loss_of = loss_of_theta()
    theta = torch.tensor([0.2, 0.1], dtype=torch.float64)

    explained = torch._dynamo.explain(loss_of)(theta.clone().requires_grad_(True))
    print(f"graphs {explained.graph_count}, graph breaks {explained.graph_break_count}")
    for reason in explained.break_reasons:
        where = reason.user_stack[-1] if reason.user_stack else None
        place = f"{Path(where.filename).name}:{where.lineno}" if where else "?"
        print(f"  {place}: {reason.reason.splitlines()[0][:100]}")
    torch._dynamo.reset()

    eager = ms_per_step(loss_of, theta, args.steps)
    print(f"eager:                    {eager:.3f} ms per forward + backward")
    compiled = torch.compile(loss_of, backend="eager")
    with_eager_backend = ms_per_step(compiled, theta, args.steps)
    print(f"compiled, backend eager:  {with_eager_backend:.3f} ms ({with_eager_backend / eager:.2f}x eager)")
    torch._dynamo.reset()
    inductor = torch.compile(loss_of)
    start = time.perf_counter()
    inductor(theta.clone().requires_grad_(True)).backward()
    first = time.perf_counter() - start
    with_inductor = ms_per_step(inductor, theta, args.steps)
    print(f"compiled, inductor:       {with_inductor:.3f} ms ({with_inductor / eager:.2f}x eager; "
          f"first call {first:.1f} s)")


if __name__ == "__main__":
    main()
