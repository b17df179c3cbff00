"""spm_data.errors: one-line messages and the error types every command turns into ``error:``."""

import pickle
import warnings

import pytest

from spm_data.errors import (ImageError, LockError, MeshError, Option, RenderError, ShardError, SpecError, SpmError,
                             SpmWarning, joined, one_line, said)


def test_one_line_joins_every_run_of_whitespace_with_one_space():
    assert one_line("a  b\n\tc\r\n d ") == "a b c d"
    assert one_line("") == "" and one_line("single") == "single"
    assert one_line(OSError(2, "No such\nfile")) == "[Errno 2] No such file"   # an exception: its message


@pytest.mark.parametrize("cls", [SpecError, MeshError, ShardError, RenderError, LockError, ImageError])
def test_every_error_is_an_spm_error(cls):
    with pytest.raises(SpmError, match="^bad thing$"):
        raise cls("bad thing")
    assert not issubclass(cls, (ValueError, OSError))   # not caught by accident as a library's error


def test_the_warning_is_a_user_warning():
    with pytest.warns(SpmWarning, match="careful"):
        warnings.warn("careful", SpmWarning)
    assert issubclass(SpmWarning, UserWarning) and not issubclass(SpmWarning, SpmError)


def test_an_error_names_options_by_key_and_a_face_by_its_own_names():
    error = SpmError(Option("min"), " 0.7 is above ", Option("max"), " 0.6")
    assert str(error) == "min 0.7 is above max 0.6" and one_line(error) == "min 0.7 is above max 0.6"
    assert error.named({"min": "--min", "max": "--max"}) == "--min 0.7 is above --max 0.6"
    assert error.named({}) == str(error) and ShardError("plain").named({"plain": "x"}) == "plain"
    assert pickle.loads(pickle.dumps(error)).named({"max": "--max"}) == "min 0.7 is above --max 0.6"


def test_joined_makes_plain_text_one_part_and_keeps_option_keys_apart():
    assert joined("a ", "b", 3) == ("a b3",) and str(SpmError(*joined("a ", "b"))) == "a b"
    parts = joined("got ", Option("max"), " 1.5", ", ok")
    assert parts == ("got ", "max", " 1.5, ok") and isinstance(parts[1], Option)
    assert said(parts) == "got max 1.5, ok" and said(parts, {"max": "--max"}) == "got --max 1.5, ok"
