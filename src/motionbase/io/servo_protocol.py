"""The thesis's Arduino servo protocol (appendix A.3): ``<decimal degrees><p|q|r>``.

Each command is the decimal digits of a servo angle in integer degrees followed by a letter
naming the servo: ``p`` for servo 1, ``q`` for servo 2, ``r`` for servo 3. A frame for the
three servos is ``b"90p45q120r"``. The link runs at 19200 baud; the board prints ``Rolling``
once it is ready.

The encoder refuses anything but integers 0..180 (it never clips). The decoder is the
firmware's state machine (``firmware/motionbase_3rrr/motionbase_3rrr.ino``), made robust where
the thesis's sketch was fragile: a letter without digits, a value above 180, more than three
digits, or a number interrupted by any other byte (the whole command up to the next letter) are
dropped instead of being written to a servo. Bytes between commands (``\r``, ``\n``, spaces)
are ignored.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from motionbase.errors import SinkError

__all__ = ["LETTERS", "SERVO_MIN_DEG", "SERVO_MAX_DEG", "encode", "ServoDecoder", "decode"]

#: Servo letters in servo order (index 0, 1, 2 = servo 1, 2, 3).
LETTERS = b"pqr"
SERVO_MIN_DEG = 0
SERVO_MAX_DEG = 180
_MAX_DIGITS = 3


def encode(servo_deg: Sequence[int]) -> bytes:
    """Encode integer degrees for servos 1, 2, 3 as ``b"<d1>p<d2>q<d3>r"``.

    Parameters
    ----------
    servo_deg : sequence of 3 int
        Servo commands, integer degrees in 0..180.

    Raises
    ------
    SinkError
        A value that is not an integer in 0..180, or not exactly three values: nothing out
        of range is ever put on the wire.
    """
    if len(servo_deg) != 3:
        raise SinkError(f"servo command: expected 3 values, got {len(servo_deg)}")
    out = []
    for i, v in enumerate(servo_deg):
        try:
            iv = int(v)
        except (TypeError, ValueError, OverflowError):
            iv = -1
        if iv != v or not SERVO_MIN_DEG <= iv <= SERVO_MAX_DEG:
            raise SinkError(
                f"servo {i + 1}: command {v!r} is not an integer in {SERVO_MIN_DEG}.."
                f"{SERVO_MAX_DEG} deg (refused, not clipped)"
            )
        out.append(b"%d%c" % (iv, LETTERS[i]))
    return b"".join(out)


class ServoDecoder:
    """Streaming decoder, byte for byte the firmware's state machine.

    ``feed(data)`` returns the commands completed by ``data`` as ``(servo_index, degrees)``
    pairs, ``servo_index`` 0, 1 or 2. State carries across calls (a command may be split
    between reads). ``dropped`` counts the commands refused (value above 180, letter without
    digits, number broken by a stray character).
    """

    def __init__(self) -> None:
        self._value = 0
        self._digits = 0
        self._poisoned = False
        self.dropped = 0

    def feed(self, data: bytes | bytearray | Iterable[int]) -> list[tuple[int, int]]:
        out: list[tuple[int, int]] = []
        for ch in bytes(data):
            if 0x30 <= ch <= 0x39:  # '0'..'9'
                if self._digits <= _MAX_DIGITS:  # past 4 digits the value is dead anyway
                    self._value = self._value * 10 + (ch - 0x30)
                self._digits += 1
                continue
            idx = LETTERS.find(bytes([ch]))
            if idx >= 0:
                ok = 0 < self._digits <= _MAX_DIGITS and self._value <= SERVO_MAX_DEG
                if ok and not self._poisoned:
                    out.append((idx, self._value))
                else:
                    self.dropped += 1
                self._poisoned = False
            elif self._digits:
                # a number broken by a stray byte: drop it and the rest up to the next letter
                self._poisoned = True
            self._value = 0
            self._digits = 0
        return out


def decode(data: bytes) -> list[tuple[int, int]]:
    """Decode a complete byte string (see :class:`ServoDecoder`)."""
    return ServoDecoder().feed(data)
