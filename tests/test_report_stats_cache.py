"""report.html's G-code statistics kept in the page: a big file is read once.

The sender's reading of a 96k-line G-code took seconds at every report. The page keeps
its figures with what they were counted from (the file's SHA-256, never its size or
time, the profile and the code that reads it), so a kept figure is never an earlier
file's, and the next report reads them back.
"""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

import pytest

from scratchfab.machine.profile import load_profile
from scratchfab.pipeline import report
from scratchfab.pipeline.report import cached_gcode_statistics, gcode_statistics, write_report

LINES = ["G21 G90", "G0 Z5", "G0 X1 Y1", "G1 Z-0.1 F200", "G1 X5 Y5 F600", "G0 Z5", "M2"]


def _job(tmp_path):
    gcode = tmp_path / "job" / "export" / "board.gcode"
    gcode.parent.mkdir(parents=True)
    gcode.write_text("\n".join(LINES) + "\n")
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


def _report(job, profile=None):
    """write_report, its page's figures as cached_gcode_statistics reads them back."""
    page = job / "report.html"
    stats, record = cached_gcode_statistics(job, profile)
    page.write_text(f"<html><head>{record}</head></html>")
    return stats


def test_a_second_report_reads_the_kept_figures_which_are_the_reading_s(tmp_path, reads):
    job, gcode = _job(tmp_path)
    write_report(job)
    first = (job / "report.html").read_text()
    assert "<script type='application/json' id='gcode-statistics'>" in first
    write_report(job)
    assert len(reads) == 1  # the second report read no G-code
    assert (job / "report.html").read_text() == first
    # the reference: the sender's reading itself, no record
    assert cached_gcode_statistics(job, None)[0] == gcode_statistics(gcode)
    assert sorted(p.name for p in job.iterdir()) == ["export", "report.html"]  # no new file


def test_a_changed_file_of_the_same_size_and_time_is_read_again(tmp_path, reads):
    job, gcode = _job(tmp_path)
    before = _report(job)
    stamp = gcode.stat()
    # the same length, the same time: the cut made a comment, which is not sent
    gcode.write_text(gcode.read_text().replace("G1 X5 Y5 F600", "(1 X5 Y5 F60)"))
    os.utime(gcode, ns=(stamp.st_atime_ns, stamp.st_mtime_ns))
    assert gcode.stat().st_size == stamp.st_size
    after = _report(job)
    assert len(reads) == 2
    assert after == gcode_statistics(gcode)
    assert after["sent"] == before["sent"] - 1


def test_another_profile_is_counted_for_itself(tmp_path, reads):
    job, gcode = _job(tmp_path)
    profile = load_profile("grbl-3018-diamond")
    alone = _report(job)
    told = _report(job, profile)
    assert len(reads) == 2
    assert told["cuts"] != alone["cuts"]  # its Z heights: X5 Y5 cuts nothing on it
    assert told == gcode_statistics(gcode, profile)
    _report(job, profile)
    assert len(reads) == 2  # now kept for that profile


def test_a_damaged_or_foreign_record_is_counted_around(tmp_path, reads):
    job, gcode = _job(tmp_path)
    page = job / "report.html"
    opening = "<script type='application/json' id='gcode-statistics'>"
    page.write_text(f"{opening}{{not json</script>")
    assert cached_gcode_statistics(job, None)[0] == gcode_statistics(gcode)
    # right shape, figures another key's: not shown
    page.write_text(f'{opening}{{"key": {{"gcode": "0"}}, "stats": {{"lines": 99}}}}</script>')
    assert cached_gcode_statistics(job, None)[0]["lines"] == len(LINES)
    page.write_bytes(b"\xff\xfe not UTF-8")
    assert cached_gcode_statistics(job, None)[0]["lines"] == len(LINES)
    assert len(reads) == 3


def test_figures_counted_while_the_file_changed_are_not_kept(tmp_path, monkeypatch):
    job, gcode = _job(tmp_path)
    real = report.gcode_statistics

    def changing(path, profile=None):
        stats = real(path, profile)
        gcode.write_text(gcode.read_text() + "G0 X0 Y0\n")  # the export writes it again
        return stats

    monkeypatch.setattr(report, "gcode_statistics", changing)
    assert cached_gcode_statistics(job, None)[1] == ""
    monkeypatch.setattr(report, "gcode_statistics", real)
    assert _report(job)["lines"] == len(LINES) + 1


def test_a_quoted_line_cannot_end_the_record(tmp_path, monkeypatch):
    """A refusal quoting a G-code line with ``</script>`` stays inside the record."""
    job, gcode = _job(tmp_path)
    said = {"lines": 7, "sent": "none: stream refuses the file (line 2: '(</script><b>x)')"}
    monkeypatch.setattr(report, "gcode_statistics", lambda path, profile=None: dict(said))
    stats, record = cached_gcode_statistics(job, None)
    assert record.count("</script>") == 1 and record.endswith("</script>")
    (job / "report.html").write_text(record)
    monkeypatch.setattr(report, "gcode_statistics", None)  # read back, not counted
    assert cached_gcode_statistics(job, None)[0] == stats == said


def test_an_edited_reader_anywhere_in_the_package_counts_again(tmp_path, reads, monkeypatch):
    """The reading goes through the unit codes, the profile's words, the file reader...

    so the key hashes every module: an edit of one the sender's files do not name, here a
    copy of the package standing for the installed one, is a new reader.
    """
    package = tmp_path / "package"
    shutil.copytree(
        Path(report.__file__).resolve().parent.parent,
        package,
        ignore=shutil.ignore_patterns("__pycache__"),
    )
    monkeypatch.setattr(report, "_PACKAGE", package)
    job, _ = _job(tmp_path)
    _report(job)
    _report(job)
    assert len(reads) == 1
    for edited in ("machine/grbl_codes.py", "fileio.py", "machine/profile.py"):
        module = package / edited
        module.write_text(module.read_text() + "\n# edited\n")
        _report(job)
        _report(job)
    assert len(reads) == 4  # once for each edit, then kept
    (package / "machine" / "new_reader.py").write_text("")
    _report(job)
    assert len(reads) == 5


def test_the_same_bytes_under_another_name_are_counted_for_it(tmp_path, reads, monkeypatch):
    """A refusal names the file: the record of board.gcode is not another name's."""
    from scratchfab.model import job as job_module

    job, gcode = _job(tmp_path)
    gcode.write_text("G21 G90\nG0 Z5\n$H\nM2\n")  # refused, the file named
    assert "board.gcode:3" in _report(job)["sent"]
    monkeypatch.setattr(job_module, "_EXPORT_STEM", "plate")
    other = gcode.with_name("plate.gcode")
    other.write_bytes(gcode.read_bytes())
    told = _report(job)
    assert len(reads) == 2
    assert told == gcode_statistics(other)
    assert "plate.gcode:3" in told["sent"]


def _in_thread(call, seconds=20.0):
    """``call()``'s value, or fails where it has not returned within ``seconds``."""
    got: list[object] = []
    worker = threading.Thread(target=lambda: got.append(call()), daemon=True)
    worker.start()
    worker.join(seconds)
    return worker, got


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_for_a_page_is_not_read(tmp_path, reads):
    job, gcode = _job(tmp_path)
    os.mkfifo(job / "report.html")
    worker, got = _in_thread(lambda: cached_gcode_statistics(job, None))
    if worker.is_alive():  # let the waiting reader go before failing
        os.close(os.open(job / "report.html", os.O_WRONLY | os.O_NONBLOCK))
        worker.join(5)
    assert got, "the report waited for a writer of the FIFO report.html"
    assert got[0][0] == gcode_statistics(gcode)
    assert len(reads) == 1
    # the page written over the FIFO (a file put in its place), then read back
    worker, _ = _in_thread(lambda: write_report(job))
    assert not worker.is_alive()
    assert (job / "report.html").is_file()
    cached_gcode_statistics(job, None)
    assert len(reads) == 2


def test_a_folder_for_a_page_is_counted_around(tmp_path, reads):
    job, gcode = _job(tmp_path)
    (job / "report.html").mkdir()
    assert cached_gcode_statistics(job, None)[0] == gcode_statistics(gcode)


def test_the_record_is_looked_for_in_the_page_s_head_only(tmp_path, reads):
    job, gcode = _job(tmp_path)
    _, record = cached_gcode_statistics(job, None)
    page = job / "report.html"
    near = report._RECORD_WITHIN - len(record) - 100
    page.write_text("x" * near + record + "x" * 10_000_000)
    assert cached_gcode_statistics(job, None)[0] == gcode_statistics(gcode)
    assert len(reads) == 1  # found near the end of the head, the rest not read
    page.write_text("x" * (report._RECORD_WITHIN + 1) + record)
    assert cached_gcode_statistics(job, None)[0] == gcode_statistics(gcode)
    assert len(reads) == 2  # past the head: counted again
