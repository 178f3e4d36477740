"""Exceptions that mean "the user asked for something wrong", reported without a traceback."""

from __future__ import annotations


class ScratchfabError(Exception):
    """A user-facing error: the CLI prints its message (a line, a stream's fault with its advice lines) and exits non-zero."""

    exit_code = 2

    def __str__(self) -> str:
        # a path or name given in code may hold a NUL, which a terminal drops unseen
        return super().__str__().replace("\0", "\\0")


class Interrupted(ScratchfabError):
    """The person stopped the work (Ctrl-C) and what was done is saved; exit 130 as a shell."""

    exit_code = 130


class ConfigError(ScratchfabError):
    """A configuration or data file is invalid; the message names the file and the key or row."""


class BackendError(ScratchfabError):
    """The requested compute backend (Dr.Jit LLVM or CUDA) is not usable on this machine."""
