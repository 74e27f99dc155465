"""Progress on a terminal while one large product is corrected.

The many-files path shows a bar of files (:mod:`ipc_taichi.cli.frames`) and a
tiled run a bar of tiles (:mod:`ipc_taichi.tiling`); this module shows the
work inside one product: a bar of frames for a stack or ramp, and a bar of
iterations for a lone frame being decoupled (a 4096 x 4096 frame takes seconds
per iteration on a CPU).

:class:`TerminalProgress` is the reporter the command line hands the product
pipeline through :attr:`ipc_taichi.products.ProductOptions.progress`;
:func:`reporters` turns it into the two hooks
:func:`ipc_taichi.products.correction.correct_frames` calls. A reporter is made
only when stderr is a terminal and ``--quiet`` was not given
(:func:`terminal_progress`); a bar appears only once the work has lasted
:data:`DELAY` seconds, so a quick run prints nothing but its summary line, and
it is cleared when done (the summary line follows). The iterations of a lone
frame are counted through the ``callback`` of :func:`ipc_taichi.decouple`, which
on CUDA copies the estimate to the host after each iteration: a small cost
beside the file's I/O, paid only on a terminal.
"""

import sys
import time

__all__ = ["TerminalProgress", "terminal_progress", "reporters", "DELAY"]

#: seconds of work before a bar appears (quicker runs show none)
DELAY = 0.5


class TerminalProgress:
    """A one-line bar on a terminal, told of the work as it is done.

    Parameters
    ----------
    desc : str
        What is being done, e.g. ``"decouple"``.
    stream : file, optional
        Where the bar is drawn (default ``sys.stderr``).
    delay : float, optional
        Seconds from this object's creation before a bar is drawn (default
        :data:`DELAY`).

    Notes
    -----
    ``progress(done, total, unit)`` draws ``done`` of ``total`` ``unit`` s; a
    call with another total or unit, or a ``done`` below the last one, starts
    a new bar (e.g. the next science HDU). Use it as a context manager, or call
    :meth:`close`, to clear the bar.
    """

    def __init__(self, desc, stream=None, delay=None):
        self.desc = desc
        self.stream = sys.stderr if stream is None else stream
        self.delay = DELAY if delay is None else delay
        self._started = time.monotonic()
        self._bar = None

    def __call__(self, done, total, unit="frame"):
        bar = self._bar
        if bar is None or bar.total != total or bar.unit != unit or done < bar.n:
            from tqdm import tqdm

            self.close()
            waited = time.monotonic() - self._started
            bar = self._bar = tqdm(total=total, unit=unit, desc=self.desc, file=self.stream,
                                   leave=False, mininterval=0,
                                   delay=max(0.0, self.delay - waited))
        bar.update(done - bar.n)

    def close(self):
        """Clear the bar (if one was drawn)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __deepcopy__(self, memo):  # one live bar, shared by every copy of the options
        return self

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def terminal_progress(desc, quiet=False, stream=None):
    """A :class:`TerminalProgress` on ``stream`` (default ``sys.stderr``) when it
    is a terminal and not ``quiet``; else ``None`` (nothing is drawn)."""
    stream = sys.stderr if stream is None else stream
    if quiet or not getattr(stream, "isatty", lambda: False)():
        return None
    return TerminalProgress(desc, stream)


def reporters(progress, frames, max_iter):
    """The hooks of one array of ``frames`` frames for ``progress``.

    Returns ``(after_frame, after_iteration)``: ``after_frame(k)`` once frame
    ``k`` (1-based) of a stack is done, and the ``callback(q, estimate)`` of
    :func:`ipc_taichi.decouple`, which reports each of at most ``max_iter``
    iterations, for a lone frame. Either is ``None`` where it says nothing (a
    lone frame has no frames to count, a stack's iterations are quick); both
    are ``None`` when ``progress`` is not callable (e.g. ``True``, which asks
    only for the bar of tiles of a tiled run).
    """
    if not callable(progress):
        return None, None
    if frames > 1:
        return (lambda k: progress(k, frames, "frame")), None
    return None, (lambda q, estimate: progress(q, max_iter, "iteration"))
