"""The streaming journal: an append-only JSONL log of what the controller acknowledged.

One JSON object per line, appended and flushed as it happens (a crash can cut only the last
line, which the reader skips). Events:

- ``{"ev": "start", "file": ..., "sha256": ..., "blocks": N, "resume": bool, ...}``; the
  file relative to the job folder when both lie in one job (:meth:`Journal.recorded`), for
  messages only: a resume knows its file by ``sha256``; ``"homing"``: GRBL's ``$22``
  (true, false, null where not read), for a resume's advice on finding the position;
  ``"zeroed"`` (only where sent): the ``G10 L20`` command ``--zero-here`` sent once
  connected, where the tool stood
- ``{"ev": "ack", "i": block, "line": file_line}`` for each ``ok`` of a file block
  (``{"ev": "ack", "pre": k}`` for the k-th resume preamble block)
- ``{"ev": "error", "i": block, "line": file_line, "code": N}`` (``"pre": k`` for a resume
  preamble block; no block where none can be named, e.g. ``error:9`` mid-job, the
  controller locked in an Alarm whose message was lost) / ``{"ev": "alarm", "code": N}``
  (with ``"lost": true`` where GRBL stopped the machine at speed: a soft limit during the
  sender's feed hold still slowing down, a hard limit, a reset in motion; the position is
  likely lost. ``"lost": "maybe"``: a soft limit while the last report showed the machine
  moving, or slowing down under a hold the sender did not send: GRBL's own soft-limit hold
  or the controller's hold button)
- ``{"ev": "stop", "reason": ..., "executed_through": i|null}``: the controller was reset and
  its queue flushed; blocks after ``executed_through`` may not have run although acknowledged.
  With the sender's lift on it also holds ``"lift"``: ``{"result": "raised"|"up", "z":
  work mm, "machine_z": ..., "from_machine_z": ...}`` (raised, or already at the travel
  height), ``{"result": "raised"|"reset", "up": command}`` for a servo scribe, or
  ``{"result": "skipped"|"failed"|"interrupted", "reason": ...}``. It is written after the
  lift, so a sender killed during it leaves an unclosed session (read cautiously, below);
  resuming never reads it. A ``lost`` event may hold a skipped ``"lift"`` too. ``"lost":
  true`` on a ``stop``: the controller reset itself (its banner came unasked: a power or USB
  glitch, its reset button), which may have lost the position; a resume asks whether the
  machine was homed since (``--homed``).
- ``{"ev": "lost", "reason": ..., "executed_through": i}``: the link dropped. A controller
  that keeps power runs every block it acknowledged; one powered over the USB cable stops
  with it, and the blocks after ``executed_through`` (judged from the last position report)
  may not have run. Resume trusts the acknowledgements unless asked to re-cut those blocks.
  ``"mpos"`` and ``"wco"`` (mm, where a status report told them): where the machine stood
  by the last report; a resume that finds the controller at machine zero though ``mpos``
  was not (it reset: an Arduino resets when its port is opened) asks whether it was homed,
  and so does one whose ``lost`` event holds no ``mpos`` (no report came before the drop,
  or a journal written before it was recorded): whether it reset cannot be told.
- ``{"ev": "end", "complete": true}``

A block is *done* when a session acknowledged it and did not later flush it with a reset;
only the sessions since the last fresh (non-resume) start count. A session with no closing
event (``stop``, ``lost`` or ``end``: the sender was killed or crashed) is read like one
that ended in a reset with no known position: the next connection resets the controller
(our soft reset, an Arduino's DTR reset), so its last acknowledged blocks, up to a planner
full and the few its stepper still runs, may never have run (:func:`last_surely_run`). A resume that finds the controller at machine
zero though the last acknowledged block ended elsewhere asks whether it was homed, as after
a lost link (it reset since).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

from scratchfab.errors import ConfigError, ScratchfabError
from scratchfab.fileio import decode_json, read_input, try_lock
from scratchfab.machine.sender_program import Block, Program, plans_nothing
from scratchfab.model.job import JobLayout

#: GRBL 1.1's usable planner blocks, for a journal that does not record them.
PLANNER_BLOCKS = 15
#: Blocks GRBL 1.1's stepper may still run after its planner let them go: a block leaves
#: the planner once all its steps are in the step segment buffer (``SEGMENT_BUFFER_SIZE``
#: 6, one slot kept free), and a move shorter than a segment (10 ms) is one segment.
STEPPER_BLOCKS = 5


def default_journal_path(gcode: str | os.PathLike[str]) -> Path:
    """``JOB/stream/journal.jsonl`` for ``JOB/export/*.gcode``, else ``<file>.journal.jsonl``."""
    p = Path(gcode).resolve()
    job = JobLayout.for_export_file(p)
    if job is not None:
        return job.journal
    return p.with_name(p.name + ".journal.jsonl")


def timestamp() -> str:
    """Local time to the second, as the journal and the job's manifest record it."""
    return time.strftime("%Y-%m-%dT%H:%M:%S")


class Journal:
    """Appends events to a journal file, flushing each one."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self._handle: IO[str] | None = None
        self.failed: str | None = None  # the first write error; later writes are skipped
        self.created = False
        self._torn = False

    def open(self) -> Journal:
        """Open for appending (creating the folder) and lock it against a second stream.

        A last line cut off by a crash or a full disk is ended by the first write, so it
        stays a line of its own (:func:`read_journal` skips it when a new session follows).

        Raises:
            ScratchfabError: The journal cannot be written, another stream holds it, or the
                file exists and is not a journal (:func:`check_journal_file`; one line
                naming it).
        """
        check_journal_file(self.path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.created = not self.path.exists()
            self._handle = open(self.path, "a", encoding="utf-8", newline="\n")  # noqa: SIM115
        except OSError as exc:
            raise self._error(exc) from None
        try:
            locked = try_lock(self._handle)
        except ScratchfabError:
            self._handle.close()
            self._handle = None
            raise
        if not locked:
            self._handle.close()
            self._handle = None
            raise ScratchfabError(
                f"another stream is using {self.path}; wait for it to end (nothing was sent)"
            ) from None
        try:
            size = self.path.stat().st_size
            if size:
                with open(self.path, "rb") as handle:
                    handle.seek(size - 1)
                    torn = handle.read(1) != b"\n"
                self._torn = torn  # ended by the first write
        except OSError as exc:
            self.close()
            raise self._error(exc) from None
        return self

    def _error(self, exc: OSError) -> ScratchfabError:
        return ScratchfabError(f"{self.path}: cannot write the journal ({exc.strerror or exc})")

    def write(self, event: str, **data: Any) -> None:
        """Append one event and flush it to the OS.

        Raises:
            ScratchfabError: The journal could not be written (a full disk; one line naming
                it). Later writes are skipped, so the safe stop can still run.
        """
        if self._handle is None or self.failed is not None:
            return
        record = {"ev": event, **data}
        if event in ("start", "stop", "lost", "end", "error", "alarm"):
            record["time"] = timestamp()
        try:
            lead = "\n" if self._torn else ""
            self._handle.write(lead + json.dumps(record, separators=(",", ":")) + "\n")
            self._torn = False
            self._handle.flush()
            if event != "ack":
                os.fsync(self._handle.fileno())
        except OSError as exc:
            error = self._error(exc)
            self.failed = str(error)
            raise error from None

    def start(
        self,
        program: Program,
        resume: bool,
        start: int = 0,
        protocol: str = "",
        preamble: Sequence[str] = (),
        planner_blocks: int = PLANNER_BLOCKS,
        port: str | None = None,
        laser_mode: bool | None = None,
        wco: Sequence[float] | None = None,
        g92: Sequence[float] | None = None,
        inches: bool = False,
        steps_mm: Sequence[float] | None = None,
        homing: bool | None = None,
        zeroed: str | None = None,
    ) -> None:
        """Begin a run of ``program`` at block ``start`` (a fresh one, or a resume).

        ``port`` (the device or URL streamed to) lets a reader tell the emulator from a
        machine; ``laser_mode`` is GRBL's ``$32`` (None: not read), which decides whether an
        S change is a sync point (:func:`last_surely_run`). ``wco`` and its ``g92`` part
        (mm, None: unknown) let a resume see that the work zero moved (:func:`run_zero`);
        ``inches``: they were read in GRBL's inch reports (``$13=1``), a coarser digit.
        ``steps_mm``: GRBL's step per axis (mm, ``$100``-``$102``; 0 or None: not known),
        for the moves it may drop (:func:`last_surely_run`). ``homing``: GRBL's ``$22``
        (None: not read), so that a resume's advice before connecting knows whether ``$H``
        can find the position (:func:`run_homing`). ``zeroed``: the work zero command
        sent where the tool stood once connected (``--zero-here``), recorded where given.
        """
        self.write(
            "start",
            file=self.recorded(program.path),
            sha256=program.sha256,
            blocks=len(program.blocks),
            resume=resume,
            resume_from=(program.blocks[start].lineno if 0 < start < len(program.blocks) else None),
            protocol=protocol,
            preamble=list(preamble),
            planner=planner_blocks,
            port=port,
            laser=laser_mode,
            wco=None if wco is None else [round(float(v), 4) for v in wco],
            g92=None if g92 is None else [round(float(v), 4) for v in g92],
            inches=inches,
            steps=None if steps_mm is None else [float(v) for v in steps_mm],
            homing=homing,
            **({} if zeroed is None else {"zeroed": zeroed}),
        )

    def recorded(self, file: str | os.PathLike[str]) -> str:
        """``file`` as the journal records it (relative to the job folder, else absolute).

        Relative when the journal is a job's (``JOB/stream/journal.jsonl``) and ``file``
        lies in that job, so that a copied job names its own file.
        """
        job = JobLayout(self.path.resolve().parent.parent)
        target = Path(file).resolve()
        if self.path.resolve() == job.journal and target.is_relative_to(job.root):
            return job.relative(target)
        return str(Path(file).absolute())

    def close(self, remove_if_empty: bool = False) -> None:
        """Flush to disk, unlock and close (a journal that failed closes quietly).

        Args:
            remove_if_empty: Delete the file if :meth:`open` created it and nothing was
                written (a stream refused before sending).

        Raises:
            ScratchfabError: The last events could not be written (one line naming it).
        """
        handle, self._handle = self._handle, None
        if handle is None:
            return
        error: OSError | None = None
        try:
            handle.flush()
            os.fsync(handle.fileno())
        except OSError as exc:
            error = exc
        # Unlinked while still locked, so no other stream can take the file in between;
        # Windows cannot delete an open file, so there it goes after the close.
        remove = remove_if_empty and self.created and _is_empty(self.path)
        if remove:
            remove = not _unlink(self.path)
        try:
            handle.close()
        except OSError as exc:
            error = error or exc
        if remove:
            _unlink(self.path)
        if error is not None and self.failed is None:
            self.failed = str(self._error(error))
            raise self._error(error) from None


#: The events :class:`Journal` writes; any other ``"ev"`` is a damaged line.
EVENT_KINDS = ("start", "ack", "error", "alarm", "stop", "lost", "end")

_REPAIR = "repair the line or move the journal aside to stream from the top"


def _expected(where: str, key: str, what: str, value: Any) -> ConfigError:
    return ConfigError(f"{where}: {key!r}: expected {what}, got {json.dumps(value)}; {_REPAIR}")


def _integer(ev: dict[str, Any], key: str, lo: int, hi: int | None, where: str) -> None:
    """Refuse ``ev[key]`` unless it is an integer (not a bool) in ``lo..hi``."""
    value = ev.get(key)
    if isinstance(value, int) and not isinstance(value, bool) and lo <= value:
        if hi is None or value <= hi:
            return
    span = f"an integer >= {lo}" if hi is None else f"an integer {lo}..{hi}"
    if key not in ev:
        raise ConfigError(f"{where}: {key!r} is missing, expected {span}; {_REPAIR}")
    raise _expected(where, key, span, value)


def check_event(ev: dict[str, Any], blocks: int | None, where: str) -> int | None:
    """Refuse an event whose fields the reader uses are not what :class:`Journal` writes.

    Args:
        ev: One decoded journal line.
        blocks: The block count of the run it belongs to (its start event), None if unknown.
        where: ``file:line`` for messages.

    Returns:
        The block count of the run from here on (``ev["blocks"]`` for a start event).

    Raises:
        ConfigError: One line naming ``where``, the key and what it should hold.
    """
    kind = ev.get("ev")
    if kind not in EVENT_KINDS:
        raise _expected(where, "ev", "one of " + ", ".join(EVENT_KINDS), kind)
    if kind == "start":
        if not isinstance(ev.get("sha256"), str):
            raise _expected(where, "sha256", "the G-code file's hash (a string)", ev.get("sha256"))
        if not isinstance(ev.get("resume"), bool):
            raise _expected(where, "resume", "true or false", ev.get("resume"))
        _integer(ev, "blocks", 0, None, where)
        if "planner" in ev:
            _integer(ev, "planner", 1, None, where)
        if ev.get("laser") not in (True, False, None):
            raise _expected(where, "laser", "true, false or null (GRBL's $32)", ev.get("laser"))
        for key in ("wco", "g92"):
            if ev.get(key) is not None and xyz_of(ev[key]) is None:
                raise _expected(where, key, "null or [x, y, z] in mm", ev[key])
        if ev.get("homing") not in (True, False, None):
            raise _expected(where, "homing", "true, false or null (GRBL's $22)", ev.get("homing"))
        if not isinstance(ev.get("zeroed", ""), str):
            raise _expected(where, "zeroed", "a G10 L20 command (a string)", ev.get("zeroed"))
        steps = ev.get("steps")
        if steps is not None and not all(0.0 <= v < math.inf for v in xyz_of(steps) or [-1.0]):
            raise _expected(where, "steps", "null or [x, y, z] mm per step, each 0 or more", steps)
        return int(ev["blocks"])
    last = None if blocks is None else blocks - 1
    if kind == "ack":
        if ("i" in ev) == ("pre" in ev):
            keys = json.dumps(sorted(k for k in ev if k != "ev"))
            raise ConfigError(
                f"{where}: 'i' or 'pre': expected one of them ('i' a block 0..{last}, 'pre' "
                f"a resume preamble line), got the keys {keys}; {_REPAIR}"
            )
        if "i" in ev:
            _integer(ev, "i", 0, last, where)
        else:
            _integer(ev, "pre", 0, None, where)
    elif kind in ("stop", "lost") and ev.get("executed_through", 0) is not None:
        _integer(ev, "executed_through", -1, last, where)
    return blocks


def run_zero(
    events: Sequence[dict[str, Any]],
) -> tuple[tuple[float, float, float] | None, tuple[float, float, float] | None]:
    """The work offset and its G92 part (mm) the journal's last run streamed at.

    ``(None, None)`` where the journal did not record them (older journals, unread).
    """
    last = last_start(events)
    return xyz_of(last.get("wco")), xyz_of(last.get("g92"))


def run_zero_in_inches(events: Sequence[dict[str, Any]]) -> bool:
    """Whether the journal's last run read its work offset in inch reports (``$13=1``)."""
    return last_start(events).get("inches") is True


def run_homing(events: Sequence[dict[str, Any]]) -> bool | None:
    """GRBL's homing cycle (``$22``) as the journal's last run read it; None: not recorded."""
    homing = last_start(events).get("homing")
    return homing if isinstance(homing, bool) else None


def run_zeroed(events: Sequence[dict[str, Any]]) -> str | None:
    """The work zero command the journal's last run sent where the tool stood, else None."""
    zeroed = last_start(events).get("zeroed")
    return zeroed if isinstance(zeroed, str) else None


def _start_indices(events: Sequence[dict[str, Any]]) -> list[int]:
    """Where the journal's ``start`` events are (each begins a session)."""
    return [k for k, ev in enumerate(events) if ev.get("ev") == "start"]


def last_session(events: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The journal's events from its last ``start`` on (all of them without one)."""
    starts = _start_indices(events)
    return list(events[starts[-1] :] if starts else events)


def last_start(events: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The journal's last ``start`` event; ``{}`` where there is none."""
    session = last_session(events)
    return session[0] if session and session[0].get("ev") == "start" else {}


def xyz_of(value: Any) -> tuple[float, float, float] | None:
    """``value`` as (x, y, z) where it is a JSON list of three numbers, else None."""
    if not isinstance(value, list) or len(value) != 3:
        return None
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        return None
    return (float(value[0]), float(value[1]), float(value[2]))


def last_fresh_start(events: Sequence[dict[str, Any]]) -> int:
    """Index of the last fresh (non-resume) start event, else of the first start, else 0.

    The runs before it no longer count for a resume (a fresh start cut the board anew).
    """
    starts = _start_indices(events)
    fresh = [k for k in starts if not events[k].get("resume")]
    return fresh[-1] if fresh else (starts[0] if starts else 0)


def read_journal(path: str | os.PathLike[str]) -> list[dict[str, Any]]:
    """All complete events of a journal; a line cut off by a crash or a full disk is skipped.

    Such a line is let be only as the last line, or when a new session's start follows it.

    Every line must be a JSON object and the first a start event. From the last fresh
    (non-resume) start on, the lines that count for a resume are checked field by field
    (:func:`check_event`); damage before it cannot change a resume and is let be.

    Raises:
        ConfigError: Unreadable file, or a damaged line (naming ``file:line`` and the key).
    """
    p = Path(path)
    data = read_input(
        p, "a journal file", "no journal to resume from (stream without --resume first)"
    )
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(f"{p}: not a journal (not UTF-8 text)") from None
    events = []
    lines = text.splitlines()
    for k, line in enumerate(lines, start=1):
        try:
            event = decode_json(line)
        except json.JSONDecodeError:
            if k == len(lines) and not text.endswith("\n"):
                break  # cut off by a crash while it was written
            if k < len(lines) and _is_start(lines[k]):
                continue  # cut off (crash, full disk), ended by the next session's open
            event = None
        if not isinstance(event, dict):
            raise ConfigError(
                f"{p}:{k}: not a journal line (move the journal aside to stream from the top)"
            )
        events.append(event)
    if not events:
        return events
    if events[0].get("ev") != "start":
        raise _expected(f"{p}:1", "ev", '"start" (a journal begins with one)', events[0].get("ev"))
    first = last_fresh_start(events)
    if first > 0:
        check_event(events[0], None, f"{p}:1")
    blocks: int | None = None
    for k in range(first, len(events)):
        blocks = check_event(events[k], blocks, f"{p}:{k + 1}")
    return events


def _is_start(line: str) -> bool:
    try:
        event = decode_json(line)
    except json.JSONDecodeError:
        return False
    return isinstance(event, dict) and event.get("ev") == "start"


def check_journal_file(
    path: str | os.PathLike[str], gcode: str | os.PathLike[str] | None = None
) -> None:
    """Refuse to append to ``path`` unless it is missing, empty or a journal of ours.

    Args:
        path: The journal file to be appended to.
        gcode: The G-code file being streamed, which the journal must not be.

    Raises:
        ScratchfabError: ``path`` is the G-code file, or an existing file whose first line
            is not a start event as :class:`Journal` writes it (nothing is written).
        ConfigError: The first line is a start event with a damaged field.
    """
    p = Path(path)
    if gcode is not None and _same_file(p, Path(gcode)):
        raise ScratchfabError(
            f"{p}: is the G-code file being streamed; refusing to write the journal into it "
            "(give --journal another file)"
        )
    try:
        with open(p, "rb") as handle:
            first = handle.readline(1 << 16)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise ScratchfabError(f"{p}: cannot read the journal ({exc.strerror or exc})") from None
    if not first:
        return
    try:
        event = decode_json(first.decode("utf-8"))
    except ValueError:  # not UTF-8, not JSON
        event = None
    if not isinstance(event, dict) or event.get("ev") != "start":
        raise ConfigError(
            f"{p}: exists and is not a stream journal (its first line is not a start event); "
            "refusing to append to it (give --journal a new file or an existing journal)"
        )
    check_event(event, None, f"{p}:1")  # a damaged journal of ours: name the key


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def last_surely_run(
    blocks: Sequence[Block],
    acked: Sequence[int],
    planner_blocks: int,
    laser_mode: bool | None = None,
    step_mm: Sequence[float] = (0.0, 0.0, 0.0),
) -> int:
    """The last of the ``acked`` blocks (in order) that surely ran, without a position.

    After its last acknowledgement the controller may still hold ``planner_blocks``
    motion blocks, and GRBL's stepper keeps running the segments of up to
    :data:`STEPPER_BLOCKS` blocks the planner has let go (short moves); counting those
    and one more as a margin, up to ``planner_blocks + STEPPER_BLOCKS + 1`` acknowledged
    motion blocks count as unsure (a straight move of
    at most a step per axis, ``step_mm``, may hold no block: GRBL drops a move of no whole
    step, :func:`plans_nothing`; 0: not known, only moves of no length). An acknowledged sync
    block (a spindle change, G4, ...: ``Block.sync``) followed by later acknowledgements
    means everything before it ran; the last acknowledged block is unsure even when it is
    a sync block (a margin too). An S change in a block that moves (``Block.speed_sync``)
    counts only when ``laser_mode`` is known to be off (``$32=0``): in laser mode GRBL
    moves on through it.
    A sync block that also moves (``G1 X5 S700``, ``G1 X5 M3``) waited only for the moves
    before it: its own move was queued, not surely run. Returns -1 when none surely ran.
    """
    if not acked:
        return -1
    earliest = acked[-1]
    motions = 0
    for i in reversed(acked):
        b = blocks[i]
        synced = b.sync or (laser_mode is False and b.speed_sync)
        if synced and i != acked[-1]:
            return i - 1 if b.motion else earliest - 1
        earliest = i
        if b.motion and not plans_nothing(blocks, i, step_mm):
            motions += 1
            if motions > planner_blocks + STEPPER_BLOCKS:
                break
    return earliest - 1


def done_blocks(
    events: list[dict[str, Any]],
    sha256: str,
    path: str | os.PathLike[str],
    recut_unsure: bool = False,
    program: Program | None = None,
    recut_unclosed: bool = True,
) -> set[int]:
    """Blocks acknowledged and not flushed, over all sessions of the journal for this file.

    Args:
        events: The journal's events (:func:`read_journal`).
        sha256: The G-code file's content hash; the journal must be for the same content.
        path: The journal file, for messages.
        recut_unsure: Treat a lost link that ended the last run like a reset: blocks
            acknowledged after the last position report before it count as not done (a
            board that lost power with the cable). By default they count as done (the
            controller kept power and ran them). An earlier run's lost link was settled by
            the resume that followed it.
        program: The program, to judge which acknowledged blocks of a session with no
            closing event surely ran (:func:`last_surely_run`); without it the last
            planner-full of acknowledged blocks counts as not done.
        recut_unclosed: Count the unsure blocks of a session with no closing event as not
            done (default: the controller was reset by the next connection). False trusts
            every acknowledgement, for saying which lines are unsure.

    Raises:
        ConfigError: The journal has no start event, or its runs since the last fresh
            start were for a different file content (sha256 mismatch).
    """
    starts = _start_indices(events)
    if not starts:
        raise ConfigError(f"{path}: journal has no start event")
    first = last_fresh_start(events)  # runs before a fresh start no longer count
    done: set[int] = set()
    session: list[int] = []
    closed = True
    planner = PLANNER_BLOCKS
    laser: bool | None = None
    steps: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def settled() -> set[int]:
        if closed or not recut_unclosed or not session:
            return set(session)
        if program is not None:
            through = last_surely_run(program.blocks, session, planner, laser, steps)
        else:
            unsure = planner + STEPPER_BLOCKS + 1
            through = session[-unsure - 1] if len(session) > unsure else -1
        return {i for i in session if i <= through}

    for k, ev in enumerate(events[first:], start=first):
        kind = ev.get("ev")
        if kind == "start":
            done |= settled()
            session = []
            closed = False
            planner = int(ev.get("planner", PLANNER_BLOCKS))
            laser = ev.get("laser")  # absent (older journals) or null: unknown
            steps = xyz_of(ev.get("steps")) or (0.0, 0.0, 0.0)  # absent or null: unknown
            if ev.get("sha256") != sha256:
                raise ConfigError(
                    f"{path}: the journal was written for a different version of "
                    f"{ev.get('file', 'the file')} (content changed); cannot resume safely "
                    "(stream without --resume to start from the top)"
                )
        elif kind == "ack" and "i" in ev:
            session.append(int(ev["i"]))
        elif kind == "stop" or (kind == "lost" and recut_unsure and k > starts[-1]):
            through = ev.get("executed_through")
            limit = -1 if through is None else int(through)
            session = [i for i in session if i <= limit]
        if kind in ("stop", "lost", "end"):
            closed = True
    return done | settled()


def interrupted(events: list[dict[str, Any]], sha256: str) -> bool:
    """True if the journal's last session streamed this file content and did not finish."""
    if last_start(events).get("sha256") != sha256:
        return False
    return not any(ev.get("ev") == "end" for ev in last_session(events))


def _is_empty(path: Path) -> bool:
    """Whether ``path`` is an empty file (False when it cannot be read)."""
    try:
        return path.stat().st_size == 0
    except OSError:
        return False


def _unlink(path: Path) -> bool:
    """Delete ``path``; False when it cannot be deleted (yet)."""
    try:
        path.unlink()
    except OSError:
        return False
    return True
