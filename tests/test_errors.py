"""spm_data.errors: one-line messages and the error types every command turns into ``error:``."""

import warnings

import pytest

from spm_data.errors import (ImageError, LockError, MeshError, RenderError, ShardError, SpecError, SpmError,
                             SpmWarning, one_line)


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
