"""scripts/coil_from_mat.py takes any copy's matrix names (--images KEY --labels KEY) and says which
it holds; benchmarks/real_coil.py takes the images or the folder spm-data import wrote, or says in
one error line what it takes."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _script(path: str, name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _turntable_rows(objects=2, side=8):
    """72 views per object, a bright bar turning 5 degrees a view, rows column-major (MATLAB's)."""
    import cv2

    rows, labels = [], []
    for obj in range(1, objects + 1):
        for view in range(72):
            image = np.zeros((side * 4, side * 4), np.uint8)
            angle = np.radians(5 * view)
            c = side * 2
            cv2.line(image, (int(c - c * np.cos(angle)), int(c - c * np.sin(angle))),
                     (int(c + c * np.cos(angle)), int(c + c * np.sin(angle))), 120 + 60 * obj, 3)
            image = cv2.resize(image, (side, side), interpolation=cv2.INTER_AREA)
            rows.append(image.T.ravel() / 255.0)
            labels.append(obj)
    return np.array(rows), np.array(labels)[:, None]


def test_coil_from_mat_reads_x_gnd_and_any_names_given(tmp_path, capsys):
    from scipy.io import savemat

    coil = _script("scripts/coil_from_mat.py", "coil_from_mat")
    X, y = _turntable_rows()
    savemat(tmp_path / "xgnd.mat", {"X": X, "gnd": y})
    savemat(tmp_path / "own.mat", {"imgs": X, "lab": y})
    assert coil.main([str(tmp_path / "xgnd.mat"), "--out", str(tmp_path / "a")]) == 0
    assert len(list((tmp_path / "a").glob("obj*__*.png"))) == 144
    with pytest.raises(SystemExit) as refused:
        coil.main([str(tmp_path / "own.mat"), "--out", str(tmp_path / "b")])
    assert str(refused.value) == (f"error: {tmp_path / 'own.mat'}: no known pair of image and label matrices "
                                  "(fea/gnd, X/Y, data/class, X/gnd, fea/Y); it holds imgs, lab: give them with "
                                  "--images KEY --labels KEY")
    with pytest.raises(SystemExit, match=r"no matrix fea; it holds imgs, lab$"):
        coil.main([str(tmp_path / "own.mat"), "--out", str(tmp_path / "b"), "--labels", "lab"])
    assert coil.main([str(tmp_path / "own.mat"), "--out", str(tmp_path / "b"), "--images", "imgs",
                      "--labels", "lab"]) == 0
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == sorted(p.name for p in (tmp_path / "b").iterdir())


def test_real_coil_takes_an_imported_folder_and_says_what_it_takes(tmp_path, capsys):
    from spm_data.formats.coil100 import import_coil20
    from tests.helpers import coil_image, png_bytes

    real = _script("benchmarks/real_coil.py", "real_coil")
    (tmp_path / "pngs").mkdir()
    for view in range(3):
        (tmp_path / "pngs" / f"obj1__{view}.png").write_bytes(png_bytes(coil_image(1, 5 * view)))
    import_coil20(tmp_path / "pngs", tmp_path / "imp")
    assert real.imported_layout(tmp_path / "imp") == "coil20" and real.imported_layout(tmp_path / "pngs") is None
    (tmp_path / "empty").mkdir()
    for folder in (tmp_path / "empty", tmp_path / "nowhere"):
        assert real.main([str(folder), "--out", str(tmp_path / "out")]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: {folder}: ") and err.count("\n") == 1 and "spm-data import coil20|coil100" \
            in err, err
