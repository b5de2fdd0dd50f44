"""Train (or continue) the generic corner network `corners-any` (train/network/anyfit.py).

It starts from the shipped chessboard corner graph (its weights read back; the chessboard is
a training texture, not a test one) and trains on renders of the texture bank drawn on the fly.
Running it again continues from `OUT/last.pt`. CPU budget on this 2-core machine: one torch
thread at `nice 5` (the machine is shared), about 7 images / s, so the default 6,000 steps of
24 images take about 6 h; the checkpoint of any step is usable (`best.pt`, picked on a fixed
validation batch of other textures). Where torch sees a GPU it trains there.

    nohup nice -n 5 python scripts/train_any.py runs/any > runs/any/train.log 2>&1 &
"""

from __future__ import annotations

import argparse
from pathlib import Path

from service.core.paths import REPO_ROOT
from train.network.anyfit import GenericConfig, train_generic

DEFAULT_INIT = REPO_ROOT / "models" / "chessboard-corners-160x120.onnx"


def main() -> None:
    """Parse the options and run `train_generic`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="run folder (last.pt, best.pt, log.jsonl)")
    parser.add_argument("--steps", type=int, default=GenericConfig.steps)
    parser.add_argument("--batch-size", type=int, default=GenericConfig.batch_size)
    parser.add_argument("--lr", type=float, default=GenericConfig.lr)
    parser.add_argument("--threads", type=int, default=GenericConfig.threads)
    parser.add_argument("--device", default="auto", choices=("auto", "cpu", "cuda"))
    parser.add_argument("--eval-every", type=int, default=GenericConfig.eval_every)
    parser.add_argument("--val-count", type=int, default=GenericConfig.val_count)
    parser.add_argument("--init", type=Path, default=DEFAULT_INIT, help="'none': from scratch")
    args = parser.parse_args()
    config = GenericConfig(
        out=args.out,
        steps=args.steps,
        batch_size=args.batch_size,
        lr=args.lr,
        threads=args.threads,
        device=args.device,
        eval_every=args.eval_every,
        val_count=args.val_count,
        init=None if str(args.init) == "none" else args.init,
    )
    state = train_generic(config, say=lambda s: print(s, flush=True))
    print(f"done: step {state['step']}, best {state['best']}", flush=True)


if __name__ == "__main__":
    main()
