"""The hold's question names its choices once.

Asked after Ctrl-C on a terminal, it read "machine held: [r]esume or [s]top (...) (r, s)
[s]:": click added the choices the text already names. An answer not among them is asked
again (click's own refusal), and the default stays the safe stop.
"""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from scratchfab.cli import stream_cmd


@pytest.mark.parametrize(
    ("typed", "answer"), [("r\n", "resume"), ("\n", "stop"), ("x\ns\n", "stop")]
)
def test_the_hold_question_names_its_choices_once(monkeypatch, typed, answer):
    monkeypatch.setattr(stream_cmd, "stdin_is_a_terminal", lambda: True)
    with CliRunner().isolation(input=typed) as (_, stderr, _):
        got = stream_cmd.ask_resume_or_stop(lambda text: None)
        shown = stderr.getvalue().decode()
    assert got == answer
    prompts = re.findall(r"machine held: [^\n]*?: ", shown)
    assert prompts and len(prompts) == typed.count("\n"), shown
    for prompt in prompts:
        assert prompt.count("[r]esume") == 1 and prompt.count("[s]top") == 1, prompt
        assert "(r, s)" not in prompt and prompt.endswith("[s]: "), prompt
