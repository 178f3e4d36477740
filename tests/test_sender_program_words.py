"""The sender's G-code reader: the words Grbl 1.1 reads and refuses, and its pre-processing.

Each row's verdict follows Grbl 1.1h's own parser: ``protocol.c`` drops whitespace,
control characters, ``/`` and comments and upper-cases the line; ``gc_execute_line``
(``gcode.c``) then reads words, each a letter A-Z (else error:1, expected command letter)
and a number as ``read_float`` (``nuts_bolts.c``) reads it: an optional ``+``/``-``, then
digits with at most one ``.``, at least one digit (else error:2, bad number format); the
number ends at the first other character, which must be the next word's letter. Each row
is also checked against the emulator's word reader (:mod:`scratchfab.machine.grblsim_gcode`),
written from the same source separately.
"""

from __future__ import annotations

import random

import pytest
from click.testing import CliRunner
from test_stream import read_record

from scratchfab.cli import main
from scratchfab.errors import ConfigError
from scratchfab.machine.grblsim_gcode import GcodeError, _words
from scratchfab.machine.sender_program import load_program, strip_block

#: (line as written, why GRBL reads it)
ACCEPTED = [
    ("G0 X.5", "read_float takes a point before the first digit"),
    ("G0 X-0.5", "a leading minus"),
    ("G0 X+1", "a leading plus"),
    ("G0 X1.", "a point after the digits: one digit is enough"),
    ("G0 X-.5", "sign, then point, then digit"),
    ("G0 X00012.50", "leading and trailing zeros are digits"),
    ("G0 X123456789", "past 8 digits read_float drops digits, it does not fail"),
    ("G0 X 1.5 Y -2", "pre-parsing drops spaces, also inside a word"),
    ("g0 x1 y2", "pre-parsing upper-cases letters"),
    ("G0 X1 (decimal 1,5; or 1*2) Y2", "a ( ) comment is dropped, ';' and ',' inside too"),
    ("G0 X1 ; Y, 1,5", "a ; comment is dropped to the line's end"),
    ("G0 X1 (unclosed, 1,5", "an unclosed ( comment runs to the line's end"),
    ("N10 G0 X1", "N is a word letter (a line number)"),
    ("/G0 X1", "pre-parsing drops the block delete '/'"),
    ("G0\tX1", "a tab is whitespace"),
]

#: (line as written, GRBL's error, the word the message names, why)
REFUSED = [
    ("G0 X1,5", 1, "X1,5", "the number ends at ',', which is no letter"),
    ("G0 X1 Y", 2, "Y", "a letter at the line's end has no number"),
    ("G0 X1 Y2 Z", 2, "Z", "the same after several words"),
    ("X", 2, "X", "a lone letter"),
    ("G0 XY1", 2, "X", "X followed by a letter: no digit"),
    ("G0 X,5", 2, "X,5", "',' is no digit: X has no number"),
    ("G0 X.", 2, "X.", "a point without a digit"),
    ("G0 X- Y1", 2, "X-", "a sign without a digit"),
    ("G0 X+-1", 2, "X+-1", "one sign only"),
    ("G0 X1.5.3", 1, "X1.5.3", "a second point ends the number"),
    ("N10 G0 X1*45", 1, "X1*45", "a checksum: '*' is no letter"),
    ("G0 X1 %", 1, "X1%", "'%' inside a line is kept by pre-parsing, and is no letter"),
    ("G0 X#1", 2, "X#1", "'#' parameters: X has no number"),
    ("G0 X[1+2]", 2, "X[1+2]", "expressions: X has no number"),
    ("G0 X1 #1", 1, "X1#1", "'#' where a letter belongs"),
]


def _grbl_words(block: str) -> int:
    """The emulator's verdict on a stripped block: 0 (read) or its error code."""
    try:
        _words(block)
    except GcodeError as exc:
        return exc.code
    return 0


def _job(tmp_path, line: str):
    path = tmp_path / "job.gcode"
    path.write_text(f"(header)\n\nG21 G90\n{line}\nG0 X0 Y0\n")
    return path


@pytest.mark.parametrize(("line", "why"), ACCEPTED, ids=[r[0] for r in ACCEPTED])
def test_the_reader_takes_what_grbl_reads(tmp_path, line, why):
    assert _grbl_words(strip_block(line)) == 0, why
    program = load_program(_job(tmp_path, line))
    assert [b.lineno for b in program.blocks] == [3, 4, 5]


@pytest.mark.parametrize(("line", "code", "word", "why"), REFUSED, ids=[r[0] for r in REFUSED])
def test_the_reader_refuses_what_grbl_answers_with_an_error_naming_line_and_word(
    tmp_path, line, code, word, why
):
    assert _grbl_words(strip_block(line)) == code, why
    path = _job(tmp_path, line)
    with pytest.raises(ConfigError) as exc:
        load_program(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}:4: GRBL 1.1 would refuse this line"), msg
    assert f"error:{code} " in msg and f"at {word!r}" in msg, msg
    expected = "a number after the letter" if code == 2 else "a letter A-Z and a number"
    assert expected in msg, msg


def test_stream_refuses_the_file_before_it_sends_a_line(tmp_path):
    """`scratchfab stream` says which line and word, without a traceback, and sends nothing."""
    path = _job(tmp_path, "G1 X1,5 F600")
    rec = tmp_path / "rec.jsonl"
    with CliRunner().isolation(input="") as (_, stderr, _):
        with pytest.raises(SystemExit) as exc:
            main(["stream", str(path), "--port", f"grblsim://?baud=0&record={rec}", "--yes"])
        err = stderr.getvalue().decode()
    assert exc.value.code not in (0, None)
    assert f"{path}:4:" in err and "'X1,5'" in err and "error:1" in err, err
    assert "Traceback" not in err
    sent = [] if not rec.exists() else read_record(rec)
    assert not any(e["ev"] == "rx" and e["text"].startswith("G") for e in sent)


def _grbl_preprocess(raw: str) -> str:
    """Grbl 1.1's ``protocol_main_loop`` pre-processing of a line, character by character."""
    out = []
    comment = False
    for ch in raw:
        if comment:
            comment = ch != ")"
        elif ch == ";":
            break
        elif ch == "(":
            comment = True
        elif ch > " " and ch != "/":
            out.append(ch.upper() if "a" <= ch <= "z" else ch)
    return "".join(out)


def test_strip_block_is_grbls_preprocessing_on_random_lines():
    """Random lines of comment marks, spaces, controls, letters and digits (seeded)."""
    rng = random.Random(35)
    alphabet = "()();;  \t\x0b/%gxGX1.,*-"
    for _ in range(5000):
        raw = "".join(rng.choice(alphabet) for _ in range(rng.randint(0, 14)))
        expected = _grbl_preprocess(raw)
        assert strip_block(raw) == ("" if expected == "%" else expected), repr(raw)
