"""Imported only by the sweep's and the evaluation's forkservers (never by a main process):
every run process forked from them ignores Ctrl-C (SIGINT) from its first instruction. A
terminal's Ctrl-C reaches the whole process group; the parent owns cancellation and terminates
its runs, whereas a SIGINT landing in a run process printed a traceback."""

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
