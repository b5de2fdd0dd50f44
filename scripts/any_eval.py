"""Measure the generic corner network zero-shot on objects no network saw; write the page.

Per object (the held-back test textures and the shipped book and ChArUco board): accuracy and
class-0 accuracy of the zero-shot graph on independent renders at each blur level (160 x 120),
against the object's shipped model (book, ChArUco), a model fine-tuned from the generic network
(`--fine-tuned OBJECT=MODEL.onnx`, `planar-pose object train`) and the feature-matching peer
(`train/compare/anyobject.py` says how). Writes docs/any_object.md (default) with the date and
the machine.

    python scripts/any_eval.py models/generic/corners-any-160x120.npz --run runs/any-eval \
        [--fine-tuned book=runs/book-ft/models/book-corners-160x120.onnx]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import torch

from service.core.blur import BLUR_LEVELS
from service.core.paths import REPO_ROOT
from service.core.profile import load_profile
from train.compare.anyobject import evaluate_object, mean_of, test_profiles
from train.markdown import pct, table, written_by
from train.network.export import repo_path
from train.network.zeroshot import load_generic


def page(rows: list[dict[str, Any]], generic: Path, card: dict[str, Any], command: str) -> str:
    """The Markdown page of the measured `rows` (`evaluate_object`)."""
    blur_cols = [f"blur {b}" for b in BLUR_LEVELS]
    lines = [
        "# Any object: the generic corner network, zero-shot",
        "",
        written_by(command),
        "",
        f"Generic network: `{repo_path(generic)}`"
        f" (best of its last run at step {card.get('steps')}; its card beside it names the "
        "runs before). Each object: its "
        "presence threshold measured on its own renders, then independent renders (other "
        f"cameras and backgrounds, {rows[0]['count']} per blur level, classes 0-8 balanced) "
        "answered through the service's own path (`/v1/predict`'s code), nothing known of the "
        "camera. `shipped`: the object's own trained model; `fine-tuned`: a model fine-tuned "
        "from the generic network (`object train`); `peer`: feature matching (SIFT, RANSAC, "
        "PnP), no training.",
        "",
        "## Class accuracy (class 0 accuracy) per blur level",
        "",
    ]
    body = []
    for r in rows:
        for key in ("zero_shot", "fine_tuned", "shipped", "peer"):
            if key in r:
                cells = [
                    f"{pct(v['accuracy'])} ({pct(v['class0'], 0)}){' *' if 'note' in v else ''}"
                    for v in r[key]
                ]
                body.append([r["object"], key.replace("_", "-"), *cells])
    lines += table(["object", "answered by", *blur_cols], body)
    if any("note" in v for r in rows for v in r.get("peer", [])):
        lines += ["", "\\* the peer cannot match this texture (too few SIFT features): it "
                  "answers \"no object\" on every image."]  # fmt: skip
    test = [r for r in rows if r["object"].startswith("test-")]
    if test:
        lines += ["", f"## The {len(test)} held-back test textures, mean", ""]
        lines += table(
            ["answered by", *blur_cols],
            [
                [k.replace("_", "-"), *(pct(mean_of(test, k, b)) for b in BLUR_LEVELS)]
                for k in ("zero_shot", "peer")
                if any(k in r for r in test)
            ],
        )
    lines += ["", "## Anatomy of the answers at blur 0 and blur 3", ""]
    lines += [
        "Among the images whose object was found (class > 0 answered and true): near/far "
        "right and x/y side right; found: of the images that show the object; corners: the "
        "median error px against the labels.",
        "",
    ]
    lines += table(
        ["object", "answered by", "blur", "class", "near/far", "x/y side", "found", "corners px"],
        [
            [r["object"], key.replace("_", "-"), str(b), pct(v["accuracy"]), pct(v["near_far"]),
             pct(v["side"]), pct(v["found"]),
             "-" if v["corner_px"] is None else f"{v['corner_px']:.2f}"]
            for r in rows
            for key in ("zero_shot", "fine_tuned", "shipped")
            if key in r
            for b, v in ((b, r[key][b]) for b in (0, len(r[key]) - 1))
        ],
    )  # fmt: skip
    lines += ["", "## Presence threshold per object (on its own renders)", ""]
    lines += table(
        ["object", "threshold", "present right", "absent right", "backgrounds left out"],
        [
            [
                r["object"],
                f"{r['threshold']['presence_threshold']:.2f}",
                pct(r["threshold"]["present_right"]),
                pct(r["threshold"]["absent_right"]),
                ", ".join(r["threshold"]["backgrounds_excluded"]) or "none",
            ]
            for r in rows
        ],  # fmt: skip
    )
    return "\n".join(lines) + "\n"


def _digest(path: Path | None) -> str | None:
    return None if path is None else hashlib.sha256(path.read_bytes()).hexdigest()


def _evaluate(job: tuple[Path, Path, Path, int, bool, Path | None]) -> dict[str, Any]:
    """`evaluate_object` in a worker process (one torch thread), its row printed; a row
    measured already with the same weights and options is kept (run/row.json)."""
    torch.set_num_threads(1)
    profile, generic, run, count, peer, fine_tuned = job
    done = run / "row.json"
    key = {
        "count": count,
        "generic_sha256": _digest(generic),
        "fine_tuned_sha256": _digest(fine_tuned),
    }
    if done.is_file():
        row: dict[str, Any] = json.loads(done.read_text())
        served = "side" in row["zero_shot"][0]  # measured through the service's path
        if served and all(row.get(k) == v for k, v in key.items()):
            return row
    row = evaluate_object(load_profile(profile), generic, run, count, peer, fine_tuned) | key
    done.write_text(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    """Parse the options, measure every object, write the page and the JSON beside it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("generic", type=Path, help="generic weights (.npz) or a run's .pt")
    parser.add_argument("--run", type=Path, default=Path("runs/any-eval"))
    parser.add_argument("--count", type=int, default=90, help="renders per blur level")
    parser.add_argument("--objects", nargs="*", default=["book", "charuco"])
    parser.add_argument("--no-peer", action="store_true")
    parser.add_argument("--no-held-out", action="store_true", help="only the --objects")
    parser.add_argument(
        "--fine-tuned", action="append", default=[], metavar="OBJECT=MODEL.onnx",
        help="a model of OBJECT fine-tuned from the generic network (planar-pose object train)",
    )  # fmt: skip
    parser.add_argument("--workers", type=int, default=1, help="objects measured at once")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "any_object.md")
    args = parser.parse_args()
    _, card = load_generic(args.generic)
    tuned = {}
    for item in args.fine_tuned:
        name, _, model = item.partition("=")
        if not name or not Path(model).is_file():
            parser.error(f"--fine-tuned {item!r}: OBJECT=MODEL.onnx, an existing file")
        tuned[name] = Path(model)
    held_out = [] if args.no_held_out else test_profiles(args.run / "profiles")
    profiles = held_out + [load_profile(n) for n in args.objects]
    jobs = [
        (p.path, args.generic, args.run / p.name, args.count, not args.no_peer, tuned.get(p.name))
        for p in profiles
    ]
    with ProcessPoolExecutor(args.workers, mp_context=get_context("spawn")) as pool:
        rows = list(pool.map(_evaluate, jobs))
    command = "python scripts/any_eval.py " + " ".join(sys.argv[1:])
    args.out.write_text(page(rows, args.generic, card, command))
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
