from __future__ import annotations

import pytest

from scratchfab import backend
from scratchfab.errors import BackendError


def test_missing_libllvm_is_a_clear_error_naming_the_fix(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "")  # recorded, so restored afterwards
    monkeypatch.setattr(backend, "_LIB_DIRS", (str(tmp_path),))
    (tmp_path / "libLLVM-14.so.1").write_bytes(b"")  # too old: must not be picked
    (tmp_path / "libLLVM-15.so").write_bytes(b"")
    with pytest.raises(BackendError) as info:
        backend.ensure_llvm_path()
    message = str(info.value)
    # The package comes first (wheel users have no scripts/); setup.sh is for a checkout.
    assert "sudo apt-get install libllvm19" in message and "DRJIT_LIBLLVM_PATH" in message
    assert message.index("libllvm19") < message.index("in a checkout, `bash scripts/setup.sh`")


def test_newest_libllvm_16_or_later_is_chosen(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "")  # recorded, so restored afterwards
    monkeypatch.setattr(backend, "_LIB_DIRS", (str(tmp_path),))
    for name in ("libLLVM-15.so", "libLLVM-16.so.1", "libLLVM.so.19.1", "libLLVM-17.so"):
        (tmp_path / name).write_bytes(b"")
    backend.ensure_llvm_path()
    import os

    assert os.environ["DRJIT_LIBLLVM_PATH"] == str(tmp_path / "libLLVM.so.19.1")


def test_configured_old_libllvm_is_refused(monkeypatch, tmp_path):
    old = tmp_path / "libLLVM-15.so"
    old.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(old))
    with pytest.raises(BackendError, match="LLVM 15"):
        backend.ensure_llvm_path()


def test_cli_reports_backend_error_in_one_line(monkeypatch, tmp_path, capsys):
    from scratchfab.cli import main

    monkeypatch.setattr(
        "scratchfab.backend.ensure_llvm_path",
        lambda: (_ for _ in ()).throw(BackendError("no usable libLLVM found. fix it")),
    )
    design = tmp_path / "d.toml"
    design.write_text(
        '[light]\nposition_mm = [0.0, 0.0, 100.0]\n[[views]]\nname = "v"\n'
        "position_mm = [0.0, 0.0, 100.0]\nresolution = [4, 4]\n"
    )
    csv = tmp_path / "s.csv"
    csv.write_text("x0,y0,x1,y1\n0,0,1,1\n")
    with pytest.raises(SystemExit) as info:
        main(
            [
                "render",
                "--design",
                str(design),
                "--scratches",
                str(csv),
                "--out",
                str(tmp_path / "o"),
            ]
        )
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.strip() == "error: no usable libLLVM found. fix it"


@pytest.mark.parametrize(
    ("names", "chosen"),
    [
        (["libLLVM.dylib", "libLLVM-18.dylib"], "libLLVM-18.dylib"),  # a version wins
        (["libLLVM.dylib"], "libLLVM.dylib"),  # Homebrew's only name
        (["LLVM-C.dll"], "LLVM-C.dll"),  # Windows' LLVM
        (["libLLVM.so", "libLLVM-14.so"], None),  # Linux: maybe old, never guessed
    ],
)
def test_a_library_without_a_version_is_the_last_resort(monkeypatch, tmp_path, names, chosen):
    monkeypatch.setattr(backend, "_LIB_DIRS", (str(tmp_path),))
    for name in names:
        (tmp_path / name).write_bytes(b"")
    found = backend.find_libllvm()
    assert found == (None if chosen is None else str(tmp_path / chosen))


@pytest.mark.parametrize(
    ("platform", "raises", "fix"),
    [("linux", True, "apt-get install libllvm19"), ("darwin", False, "brew install llvm")],
)
def test_missing_libllvm_off_linux_is_left_to_drjit(monkeypatch, tmp_path, platform, raises, fix):
    import os

    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "")
    monkeypatch.setattr(backend, "_LIB_DIRS", (str(tmp_path),))
    monkeypatch.setattr(backend.sys, "platform", platform)
    if raises:
        with pytest.raises(BackendError, match="no usable libLLVM"):
            backend.ensure_llvm_path()
    else:
        backend.ensure_llvm_path()  # Dr.Jit searches on its own; array_module checks
        assert os.environ["DRJIT_LIBLLVM_PATH"] == ""
    assert fix in backend.llvm_fix()
    assert "LLVM-C.dll" in backend.llvm_fix("win32")


def test_backend_available_is_what_array_module_can_start(monkeypatch) -> None:
    """True where :func:`array_module` starts the backend (Dr.Jit's own answer for CUDA),
    False where it raises: a DRJIT_LIBLLVM_PATH that does not exist."""
    import drjit as dr

    from scratchfab.backend import backend_available

    assert backend_available("llvm") is True  # the suite runs on it
    assert backend_available("cuda") is bool(dr.has_backend(dr.JitBackend.CUDA))
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/nonexistent/libLLVM-19.so")
    assert backend_available("llvm") is False
