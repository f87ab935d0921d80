"""``python -m analysis report DATA --out REPORT``: the command; the report itself is :mod:`analysis.report`."""

from __future__ import annotations

import argparse
import gc
import multiprocessing
import os
import signal
import sys
import threading
import warnings
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager, nullcontext
from multiprocessing.connection import wait
from pathlib import Path

from plumbing.outdir import output_folder

from analysis.config import AnalysisConfig, check_data_folder

#: what a report folder holds (a folder of these alone, without the output marker, is an older version's
#: report, which --force replaces)
REPORT_FILES = ("report.md", "report.html", "*.csv", "fig_*")


def run(args: argparse.Namespace) -> int:
    """The ``report`` command: analyse the study folder and write tables, figures and report.md/.html; returns the exit code."""
    cfg = AnalysisConfig(reference=args.reference, margin=args.margin, group=args.group, alpha=args.alpha,
                         models=not args.no_models)
    out = Path(args.out)
    # written beside --out and swapped in whole, one writer at a time (plumbing.outdir): an interrupted or
    # failed report leaves the earlier one as it was; an earlier report without --force is refused first, and
    # an --out that is, holds or lies inside the data (or any study's data) whatever --force
    folder = output_folder(out, args.force, inputs=[(args.data, "the data folder")], command="analysis report",
                           own=REPORT_FILES).open()
    with folder:
        check_data_folder(args.data)    # before the drawing process starts: a wrong path is reported at once
        written = _report(args, cfg, folder.path, out)
    warning_type = written.pop("warning_type")
    for w in written.pop("caught"):
        if issubclass(w.category, warning_type):
            print(f"warning: {w.message}", file=sys.stderr)
    for note in written["notes"]:
        print(f"note: {note}", file=sys.stderr)
    print(f"wrote {len(written['tables'])} tables, {len(written['figures'])} figures, "
          f"{_moved(written['md'], folder)} and {_moved(written['html'], folder)}")
    return 0


def _moved(path, folder) -> Path:
    """Where ``path``, written into the staging folder of ``folder``, is now that it was swapped in."""
    return folder.out / Path(path).relative_to(folder.path)


def _report(args: argparse.Namespace, cfg: AnalysisConfig, out: Path, final: Path) -> dict:
    """Analyse ``args.data`` and write the report into ``out`` (swapped in later as ``final``); returns :func:`analysis.report.write_report`'s
    dict plus the warnings caught (``caught``, ``warning_type``)."""
    # the drawing process starts first, so that its imports overlap the ones below
    with (nullcontext() if args.no_figures else figure_process()) as pool:
        # the cyclic garbage collector pauses for the command: the modules and tables it creates live until
        # it ends, and the ~600 automatic collections of a report walked them again and again (~0.3 s); the
        # report makes little cyclic garbage (the peak memory at 10,000 subjects stays within its spread)
        collecting = gc.isenabled()
        gc.disable()
        try:
            # the drawing process, idle until the study is loaded, reads the session files while this one
            # imports the statistics and reads the trials files
            # imported after the fork (figure_process; a thread of pyarrow's would forbid it), while the drawing
            # process imports matplotlib
            from analysis.load import AnalysisWarning, submit_sessions  # deferred: pandas, 1.9 s CPU, after the fork

            sessions = submit_sessions(args.data, pool)
            # the statistics are imported while the drawing process reads the session files
            from analysis import pipeline, report  # deferred: statsmodels + scipy, 3.0 s CPU, during the session reads

            # then it lists the subject folders holding traces while this one loads the study, and draws
            # Figure 4.20 (its taps read here from the traces once the study is loaded) while this one
            # computes the statistics
            traced = report.list_traces(sessions[1], pool)
            started = []

            def loaded(study):
                if pool is not None:     # Figure 4.20 fails alone: its note says why (analysis.report)
                    notes = []
                    got = report.attempt_figure(out / "fig_4_20_accelerations.png", notes, report.start_accelerations,
                                                study, out, args.velocity, pool, traced)
                    started.append(got if got is not None else (None, notes))

            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", AnalysisWarning)
                res = pipeline.analyse(args.data, cfg, sessions=sessions, loaded=loaded)
                written = report.write_report(res, out, figures=not args.no_figures, target_v_m_s=args.velocity,
                                              pool=pool, accelerations=started[0] if started else None,
                                              final_dir=final)
        finally:
            if collecting:
                gc.enable()
    return dict(written, caught=caught, warning_type=AnalysisWarning)


@contextmanager
def figure_process():
    """An executor with a second process for :func:`analysis.report.make_figures`, or None.

    The figures cost the same at any number of subjects (~2.5 s of matplotlib in all): that process
    reads the session files while this one imports the statistics and reads the trials files, then
    draws Figure 4.20 (once the study is loaded; the taps are read from the traces here) and Figure
    4.19 while this one computes the statistics and draws Figures 4.18 and 4.17. It is forked first,
    once matplotlib is imported, while this process runs a single thread (a fork of a process running
    other threads, such as pyarrow's readers, can copy a lock one of them holds and deadlock), and
    imports the figure module (pandas) while this one imports the statistics.
    A fork, not a new interpreter: a spawned process would run the calling script's top level again.
    None where no fork is safe or possible (not Linux; other threads running, e.g. in a caller's
    process, or BLAS threads where the environment asks for more than one; a daemonic process): the
    figures are then drawn here.
    """
    # imported before the fork, so that both processes have it for the cost of one import (it starts no
    # thread; pandas would: pyarrow's allocator runs one)
    import matplotlib.pyplot  # deferred: only a report with figures needs it (0.46 s CPU)  # noqa: F401

    pool = None
    if _single_threaded():

        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("fork"),
                                   initializer=_start_drawing)
        try:
            pool.submit(int)       # forks now (an executor forks at its first task), before any thread starts
        except (OSError, AssertionError):      # no process slot left; daemonic processes have no children
            pool.shutdown(wait=False)
            pool = None
    try:
        yield pool
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


def _single_threaded() -> bool:
    """True on Linux when this process runs one thread, native ones (BLAS, allocators) included."""
    try:
        return len(os.listdir("/proc/self/task")) == 1
    except OSError:                # no /proc (not Linux): no fork
        return False


def _start_drawing() -> None:
    """Initializer of the drawing process: it leaves Ctrl-C to the main process (which stops it after the
    figure at hand), ends when the main process is gone (killed: a pool process would otherwise wait for
    its next task for ever), and does the figures' imports while the main process imports the statistics."""

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sentinel = multiprocessing.parent_process().sentinel       # readable once the main process has ended
    threading.Thread(target=_end_with_parent, args=(sentinel,), daemon=True).start()

    import analysis.figures  # deferred: the drawing process's imports (2.1 s CPU), while the study is read  # noqa: F401


def _end_with_parent(sentinel) -> None:
    """Thread of the drawing process: ends the process once ``sentinel`` (the main process's) is readable."""

    wait([sentinel])
    os._exit(1)


