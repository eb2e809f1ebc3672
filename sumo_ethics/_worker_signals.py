"""Imported only by the sweep's forkserver (never by a main process): every run process forked
from it ignores Ctrl-C (SIGINT) from its first instruction. A terminal's Ctrl-C reaches the whole
process group; the parent owns cancellation and terminates its runs, whereas a SIGINT landing in
a run process still starting up would print multiprocessing's traceback."""

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
