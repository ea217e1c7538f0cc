"""CPU milliseconds per image pair (two cameras) of the slot encoder at several batch sizes, one thread, as an
evaluation job runs it: does batching several environments' frames pay?

    .venv/bin/python bench/bench_encoder_batch.py
    .venv/bin/python bench/bench_encoder_batch.py --grid 32 --batches 2 8 32

Weights are random (the cost does not depend on them); sizes are the config's `encoders.slots_ssl`."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
import yaml

from ocpipe.encoders.ssl_slots import SSLSlotEncoder, SSLSlotsConfig

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--grid", type=int, help="cells per side (default: the config's)")
    ap.add_argument("--batches", type=int, nargs="+", default=[2, 8, 16, 32], help="images per call")
    ap.add_argument("--repeats", type=int, default=20)
    args = ap.parse_args()
    torch.set_num_threads(1)
    s = yaml.safe_load((REPO / "config" / "config.yaml").read_text())["encoders"]["slots_ssl"]
    cfg = SSLSlotsConfig(num_slots=s["num_slots"], slot_dim=s["slot_dim"], feature_dim=s["feature_dim"],
                         grid=args.grid or s["grid"], iterations=s["iterations"],
                         position_in_keys=s["position_in_keys"])
    model = SSLSlotEncoder(cfg).eval()
    print(f"grid {cfg.grid}: batch, ms per image pair (encoder), of which CNN")
    for b in args.batches:
        x = torch.rand(b, 3, cfg.grid, cfg.grid)
        with torch.inference_mode():
            model.encode(x)
            c0 = time.process_time()
            for _ in range(args.repeats):
                model.encode(x)
            enc = (time.process_time() - c0) / args.repeats
            c0 = time.process_time()
            for _ in range(args.repeats):
                model.cnn(x * 2 - 1)
            cnn = (time.process_time() - c0) / args.repeats
        print(f"{b:5d}  {2000 * enc / b:7.2f}  {2000 * cnn / b:7.2f}")


if __name__ == "__main__":
    main()
