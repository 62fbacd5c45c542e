"""The VEX V5 device program embeds :mod:`softpend.hardware.protocol` verbatim between two marker lines: check
that copy, or rewrite it (``python -m softpend.hardware.firmware --update``)."""

from __future__ import annotations

import sys
from pathlib import Path

from softpend.io.outputs import atomic_write

BEGIN_MARKER = "# ---- BEGIN softpend/hardware/protocol.py (verbatim copy; do not edit here) ----\n"
END_MARKER = "# ---- END softpend/hardware/protocol.py ----\n"
FIRMWARE_PATH = Path(__file__).resolve().parents[2] / "firmware" / "vex_v5_motor.py"
PROTOCOL_PATH = Path(__file__).resolve().parent / "protocol.py"


def embedded_protocol(firmware_path: Path = FIRMWARE_PATH) -> str:
    """The protocol source embedded in the firmware file (raises ValueError without the markers)."""
    text = Path(firmware_path).read_text()
    if BEGIN_MARKER not in text or END_MARKER not in text:
        raise ValueError(f"firmware_path {firmware_path} lacks the protocol marker lines")
    return text.split(BEGIN_MARKER, 1)[1].split(END_MARKER, 1)[0]


if __name__ == "__main__":  # pragma: no cover
    if "--update" in sys.argv:  # replace the embedded copy with the current protocol module
        text = FIRMWARE_PATH.read_text()
        head, tail = text.split(BEGIN_MARKER, 1)[0], text.split(END_MARKER, 1)[1]
        with atomic_write(FIRMWARE_PATH, "w") as handle:
            handle.write(head + BEGIN_MARKER + PROTOCOL_PATH.read_text() + END_MARKER + tail)
    ok = embedded_protocol() == PROTOCOL_PATH.read_text()
    print("firmware protocol copy is", "up to date" if ok else "OUT OF DATE (run with --update)")
    sys.exit(0 if ok else 1)
