"""``--board WxH`` and ``--resolution N|WxH`` over a table of inputs: each mistake is told for
what it is (a plotter owner typed ``50x-5`` and read "expected WxH")."""

from __future__ import annotations

import click
import pytest

from scratchfab.cli.options import SizePair


@pytest.mark.parametrize(
    ("whole", "text", "expected"),
    [
        (False, "100x80", (100.0, 80.0)),
        (False, "100x80mm", (100.0, 80.0)),
        (False, " 62.5 X 40 ", (62.5, 40.0)),
        (False, "+50x5", (50.0, 5.0)),
        (True, "128", (128, 128)),
        (True, "128x96", (128, 96)),
    ],
)
def test_good_sizes(whole, text, expected):
    assert SizePair(whole).convert(text, None, None) == expected


@pytest.mark.parametrize(
    ("whole", "text", "said"),
    [
        (False, "50x-5", "both sizes must be positive, got '50x-5'"),
        (False, "-50x5", "both sizes must be positive"),
        (False, "0x50", "both sizes must be positive"),
        (False, "50", "expected WxH such as 100x100, got '50'"),
        (False, "abcx10", "expected WxH such as 100x100"),
        (False, "50x5x5", "expected WxH"),
        (True, "-5", "expected N or WxH such as 128 or 128x96"),
        (True, "12x-3", "whole pixel counts of at least 1, got '12x-3'"),
        (True, "12.5x3", "whole pixel counts of at least 1"),
        (True, "12x3mm", "expected N or WxH"),
    ],
)
def test_bad_sizes_say_what_is_wrong(whole, text, said):
    with pytest.raises(click.BadParameter) as caught:
        SizePair(whole).convert(text, None, None)
    assert said in caught.value.message
