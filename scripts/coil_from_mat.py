"""Write a MATLAB copy of COIL-20 or COIL-100 (the ``fea``/``gnd`` matrices that circulate in
public repositories, e.g. ``COIL20.mat`` at 32 x 32 grey) as the original layout,
``obj{K}__{VIEW}.png`` with views 0..71 in turntable order, so that
``spm-data import coil20 FOLDER`` reads it. Nothing is downloaded: give the file you have.

    python scripts/coil_from_mat.py COIL20.mat --out coil20-32/
    python scripts/coil_from_mat.py COIL20.mat --out coil20-128/ --size 128   # upsampled (bicubic)
    python scripts/coil_from_mat.py COIL20.mat --out coil20-32/ --images X --labels gnd   # any other names

The images and labels are found under the names copies use (fea/gnd, X/Y, data/class, X/gnd,
fea/Y), or the names ``--images KEY --labels KEY`` give; a file holding none of them is refused
with the matrices it does hold, so the next command is plain.

Each object's rows must be its 72 views in turntable order (as in Deng Cai's copies, checked
here: turntable neighbours must be closer than 0.75 times the mean distance between any two
views, or the file is refused). Images are stored column-major, as MATLAB reshapes them.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.io import loadmat

VIEWS = 72


KNOWN_KEYS = (("fea", "gnd"), ("X", "Y"), ("data", "class"), ("X", "gnd"), ("fea", "Y"))


def read_mat(path, images_key=None, labels_key=None) -> tuple[np.ndarray, np.ndarray]:
    """(n, side, side) uint8 images and (n,) object ids of a COIL .mat file: the matrices named
    ``images_key`` and ``labels_key``, or the first pair of KNOWN_KEYS the file holds."""
    try:
        data = loadmat(path)
    except (OSError, ValueError, TypeError) as exc:
        raise SystemExit(f"error: {path}: not a readable .mat file ({str(exc).splitlines()[0] if str(exc) else exc})")
    held = sorted(k for k in data if not k.startswith("__"))
    if images_key or labels_key:
        pairs = ((images_key or "fea", labels_key or "gnd"),)
        missing = [k for k in pairs[0] if k not in data]
        if missing:
            raise SystemExit(f"error: {path}: no matrix {', '.join(missing)}; it holds {', '.join(held)}")
    else:
        pairs = KNOWN_KEYS
    for images_key, labels_key in pairs:
        if images_key in data and labels_key in data:
            X, y = np.asarray(data[images_key], dtype=np.float64), np.asarray(data[labels_key]).ravel()
            break
    else:
        raise SystemExit(f"error: {path}: no known pair of image and label matrices (fea/gnd, X/Y, data/class, "
                         f"X/gnd, fea/Y); it holds {', '.join(held)}: give them with --images KEY --labels KEY")
    if X.shape[0] != len(y):
        X = X.T
    side = int(round(math.sqrt(X.shape[1])))
    if side * side != X.shape[1] or X.shape[0] != len(y):
        raise SystemExit(f"error: {path}: {X.shape} images for {len(y)} labels; expected one square image per label "
                         "(check --images and --labels)")
    if X.max() <= 1.0:
        X = X * 255.0
    images = np.clip(np.rint(X), 0, 255).astype(np.uint8).reshape(len(y), side, side).transpose(0, 2, 1)
    return images, y.astype(np.int64)


def neighbour_ratio(views: np.ndarray) -> float:
    """Mean distance between turntable neighbours over the mean distance between any two views:
    well below 1 when the rows are in turntable order, about 1 when they are shuffled."""
    x = views.reshape(len(views), -1).astype(np.float64)
    d = np.sqrt(((x[:, None] - x[None]) ** 2).sum(axis=2))
    adjacent = np.mean([d[i, (i + 1) % len(views)] for i in range(len(views))])
    return float(adjacent / max(d[np.triu_indices(len(views), 1)].mean(), 1e-12))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("mat", help="the .mat file")
    parser.add_argument("--out", required=True, help="folder for obj{K}__{VIEW}.png")
    parser.add_argument("--size", type=int, default=None, help="resize to this side (default: as stored)")
    parser.add_argument("--images", default=None, help="the image matrix's name (default: fea, X or data)")
    parser.add_argument("--labels", default=None, help="the label matrix's name (default: gnd, Y or class)")
    args = parser.parse_args(argv)
    images, labels = read_mat(args.mat, args.images, args.labels)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for obj in np.unique(labels):
        views = images[labels == obj]
        if len(views) != VIEWS:
            raise SystemExit(f"error: object {obj} has {len(views)} views, expected {VIEWS}")
        ratio = neighbour_ratio(views)
        if ratio > 0.75:
            raise SystemExit(f"error: object {obj}: turntable neighbours are {ratio:.2f} as far apart as any two "
                             f"views; "
                             "the rows are not in turntable order")
        for view, image in enumerate(views):
            if args.size:
                image = cv2.resize(image, (args.size, args.size), interpolation=cv2.INTER_CUBIC)
            target = out / f"obj{obj}__{view}.png"
            tmp = out / f".{target.name}.partial.png"
            cv2.imwrite(str(tmp), image)
            tmp.replace(target)
    print(f"{len(labels)} images of {len(np.unique(labels))} objects in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
