"""Run `gslam ARGS...` in this process and send it SIGINT at an exact point: when the function named by
`$SIGNAL_AT` ("module_suffix:function:event[:nth]", event "call" or "return") reaches that event for the
nth time (1 by default). For the tests of the windows a timed signal hits only by chance: between a
temporary's creation and its writer's hold on it, between a run's opening and its loop.

    python tests/signal_at.py gslam process in.mcap out.mcap
"""

from __future__ import annotations

import os
import signal
import sys


def main() -> None:
    module, function, event, *nth = os.environ["SIGNAL_AT"].split(":")
    wanted = int(nth[0]) if nth else 1
    seen = 0

    def tracer(frame, kind, arg):
        nonlocal seen
        code = frame.f_code
        if seen >= wanted or code.co_name != function or not code.co_filename.endswith(module):
            return None
        if kind == "call" and event == "call":
            seen += 1
            if seen == wanted:
                os.kill(os.getpid(), signal.SIGINT)  # raised at this function's first line
            return None

        def local(frame, kind, arg):
            nonlocal seen
            if kind == "return":
                seen += 1
                if seen == wanted:
                    os.kill(os.getpid(), signal.SIGINT)  # raised in the caller, before it uses the value
            return local

        return local if event == "return" else None

    sys.argv = sys.argv[1:]
    sys.settrace(tracer)
    from pipelines.cli import run

    run()


if __name__ == "__main__":
    main()
