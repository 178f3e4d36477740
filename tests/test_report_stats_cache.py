"""report.html's G-code statistics kept in the job folder: a big file is read once.

The sender's reading of a 96k-line G-code took seconds at every report. The figures are
kept beside the report, keyed by the file's SHA-256 (never its size or time), the
profile and the code that reads it, so a kept figure is never an earlier file's.
"""

from __future__ import annotations

import os

import pytest

from scratchfab.errors import ScratchfabError
from scratchfab.pipeline import report
from scratchfab.pipeline.report import (
    GCODE_STATS_CACHE,
    cached_gcode_statistics,
    gcode_statistics,
    write_report,
)

LINES = ["G21 G90", "G0 Z5", "G0 X1 Y1", "G1 Z-0.1 F200", "G1 X5 Y5 F600", "G0 Z5", "M2"]


def _job(tmp_path, lines=LINES):
    gcode = tmp_path / "job" / "export" / "board.gcode"
    gcode.parent.mkdir(parents=True)
    gcode.write_text("\n".join(lines) + "\n")
    return tmp_path / "job", gcode


@pytest.fixture
def reads(monkeypatch):
    """The calls of the sender's reading the report makes (each the real one)."""
    calls: list[object] = []
    real = report.gcode_statistics

    def counted(path, profile=None):
        calls.append(path)
        return real(path, profile)

    monkeypatch.setattr(report, "gcode_statistics", counted)
    return calls


def test_a_second_report_reads_the_kept_figures_which_are_the_reading_s(tmp_path, reads):
    job, gcode = _job(tmp_path)
    write_report(job)
    first = (job / "report.html").read_text()
    write_report(job)
    assert len(reads) == 1  # the second report read no G-code
    assert (job / "report.html").read_text() == first
    # the reference: the sender's reading itself, no cache
    assert cached_gcode_statistics(job, None) == gcode_statistics(gcode)
    assert (job / GCODE_STATS_CACHE).is_file()


def test_a_changed_file_of_the_same_size_and_time_is_read_again(tmp_path, reads):
    job, gcode = _job(tmp_path)
    before = cached_gcode_statistics(job, None)
    stamp = gcode.stat()
    # the same length, the same time: the cut made a comment, which is not sent
    gcode.write_text(gcode.read_text().replace("G1 X5 Y5 F600", "(1 X5 Y5 F60)"))
    os.utime(gcode, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    assert gcode.stat().st_size == stamp.st_size
    after = cached_gcode_statistics(job, None)
    assert len(reads) == 2
    assert after == gcode_statistics(gcode)
    assert after["sent"] == before["sent"] - 1


def test_another_profile_is_counted_for_itself(tmp_path, reads):
    from scratchfab.machine.profile import load_profile

    job, gcode = _job(tmp_path)
    profile = load_profile("grbl-3018-diamond")
    alone = cached_gcode_statistics(job, None)
    told = cached_gcode_statistics(job, profile)
    assert len(reads) == 2
    assert told["cuts"] != alone["cuts"]  # its Z heights: X5 Y5 cuts nothing on it
    assert told == gcode_statistics(gcode, profile)
    cached_gcode_statistics(job, profile)
    assert len(reads) == 2  # now kept for that profile


def test_a_damaged_or_foreign_cache_is_counted_around(tmp_path, reads):
    job, gcode = _job(tmp_path)
    cache = job / GCODE_STATS_CACHE
    cache.write_text("{not json")
    assert cached_gcode_statistics(job, None) == gcode_statistics(gcode)
    # right shape, figures another key's: not shown
    cache.write_text('{"key": {"gcode": "0"}, "stats": {"lines": 99}}')
    assert cached_gcode_statistics(job, None)["lines"] == len(LINES)
    assert len(reads) == 2


def test_figures_counted_while_the_file_changed_are_not_kept(tmp_path, monkeypatch):
    job, gcode = _job(tmp_path)
    real = report.gcode_statistics

    def changing(path, profile=None):
        stats = real(path, profile)
        gcode.write_text(gcode.read_text() + "G0 X0 Y0\n")  # the export writes it again
        return stats

    monkeypatch.setattr(report, "gcode_statistics", changing)
    cached_gcode_statistics(job, None)
    assert not (job / GCODE_STATS_CACHE).exists()
    monkeypatch.setattr(report, "gcode_statistics", real)
    assert cached_gcode_statistics(job, None)["lines"] == len(LINES) + 1


def test_a_folder_it_cannot_write_still_gets_its_figures(tmp_path, monkeypatch):
    job, gcode = _job(tmp_path)

    def refused(path, data):
        raise ScratchfabError(f"{path}: cannot write (Read-only file system)")

    monkeypatch.setattr(report, "write_json", refused)
    assert cached_gcode_statistics(job, None) == gcode_statistics(gcode)
