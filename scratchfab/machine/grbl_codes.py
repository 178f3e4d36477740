"""GRBL 1.1 error and alarm codes with their meanings (Grbl 1.1h ``report.h`` numbering)."""

from __future__ import annotations

#: Millimetres per inch: GRBL's inch mode (G20) and inch reports (``$13=1``).
MM_PER_INCH = 25.4

#: ``error:N`` -> meaning. Codes 18 and 19 are unused in Grbl 1.1.
ERROR_CODES: dict[int, str] = {
    1: "G-code words consist of a letter and a value; the letter was not found",
    2: "a numeric value is missing or its format is invalid",
    3: "unknown or unsupported '$' system command",
    4: "a negative value was given where a positive one is required",
    5: "homing cycle requested but homing is not enabled ($22)",
    6: "step pulse time must be at least 3 microseconds",
    7: "EEPROM read failed; settings were reset to defaults",
    8: "'$' command needs the controller Idle (not allowed while running or holding)",
    9: "G-code is locked out during ALARM or jog state",
    10: "soft limits cannot be enabled without homing ($22)",
    11: "line too long: more than 79 characters after stripping (line not executed)",
    12: "the '$' setting value would exceed the maximum supported step rate",
    13: "safety door is open",
    14: "build info or startup line longer than the EEPROM line storage",
    15: "jog target exceeds the machine travel (soft limits)",
    16: "jog command has no '=' or contains a prohibited G-code",
    17: "laser mode needs PWM output",
    18: "unused in Grbl 1.1",
    19: "unused in Grbl 1.1",
    20: "unsupported or invalid G-code command (e.g. M6, G64)",
    21: "more than one G-code command from the same modal group in a block",
    22: "feed rate has not yet been set or is undefined",
    23: "G-code command needs an integer value",
    24: "two G-code commands in one block both need the XYZ axis words",
    25: "a G-code word is repeated in the block",
    26: "a G-code command needs XYZ axis words but none were given",
    27: "line number (N) out of range (1 to 9,999,999)",
    28: "a G-code command is missing its required P or L value word",
    29: "G59.x work coordinate systems are not supported",
    30: "G53 is only allowed with G0 or G1 motion",
    31: "axis words given in a block with no command or modal state that uses them",
    32: "G2/G3 arc needs at least one in-plane axis word",
    33: "motion command has an invalid target (arc geometry)",
    34: "G2/G3 arc radius (R) mathematical error",
    35: "G2/G3 arc needs at least one in-plane offset word (I, J, K)",
    36: "unused value words in the block",
    37: "G43.1 dynamic tool length offset is not on the tool's axis",
    38: "tool number greater than the maximum supported value (255)",
}

#: ``ALARM:N`` -> meaning.
ALARM_CODES: dict[int, str] = {
    1: "hard limit triggered; machine position is likely lost, {again}",
    2: (
        "soft limit: the target exceeds the machine travel; position kept unless a feed hold "
        "was slowing the machine down, reset then unlock"
    ),
    3: "reset while in motion; position is likely lost, {again}",
    4: "probe fail: the probe is not in the expected initial state",
    5: "probe fail: the probe did not contact the workpiece",
    6: "homing fail: reset during the homing cycle",
    7: "homing fail: safety door opened during homing",
    8: "homing fail: pull-off did not clear the limit switch",
    9: "homing fail: limit switch not found within the search distance",
    10: "homing fail: second switch of a dual axis not found",
}


def error_meaning(code: int) -> str:
    """The meaning of ``error:code`` (a placeholder text for codes Grbl 1.1 does not define)."""
    return ERROR_CODES.get(code, f"unknown error code {code} (not a Grbl 1.1 code)")


def alarm_meaning(code: int, again: str = "re-home") -> str:
    """The meaning of ``ALARM:code``.

    ``again``: how a lost position is found again, where the meaning says so (ALARM:1 and
    ALARM:3), as :func:`~scratchfab.machine.sender.rehome` words it for the profile and
    ``$22``: ``re-home``, ``re-home or re-zero``, ``re-zero`` where homing is off (``$H``
    answers ``error:5``), or turning homing on first.
    """
    text = ALARM_CODES.get(code, f"unknown alarm code {code} (not a Grbl 1.1 code)")
    return text.replace("{again}", again)
