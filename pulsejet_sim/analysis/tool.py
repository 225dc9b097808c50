"""The recording tools' command-line frame: parse, run, and turn their errors into exit code 2."""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from pulsejet_sim.bag.reader import BagReadError


class RecordingToolError(ValueError):
    """Bad input for a recording tool: names the file or value and what is allowed."""


def run_recording_tool(prog: str, argv: Sequence[str] | None, build, action) -> int:
    """Parse argv with the parser `build` fills, call action(args); 2 on bad input, else 0."""
    parser = argparse.ArgumentParser(prog=prog)
    build(parser)
    args = parser.parse_args(argv)
    try:
        action(args)
    except (BagReadError, RecordingToolError) as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head`: nothing left to say
        return 0
    except OSError as exc:  # unreadable file or unwritable PNG path
        if exc.filename is None:
            raise
        print(f'{prog}: error: {str(exc.filename)!r}: {exc.strerror}', file=sys.stderr)
        return 2
    return 0
