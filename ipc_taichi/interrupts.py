"""Stop requests: SIGINT/SIGTERM that a library may have swallowed.

The command line's signal handler calls :func:`request_stop` and raises;
Taichi's kernel compiler has bare ``except:`` clauses that can swallow that
exception. Long loops call :func:`check_stop`, which raises the pending
request again, and the atomic writers (:class:`ipc_taichi.fitsio.atomic_output`,
the Roman writer) never commit a file after one. :func:`clear_stop` forgets
earlier requests when a new command starts.
"""

__all__ = ["request_stop", "clear_stop", "check_stop", "stop_requested"]

_stop_requests = []


def request_stop(exc):
    """Remember that the process was asked to stop (a signal handler calls
    this, then raises ``exc``)."""
    _stop_requests.append(exc)


def clear_stop():
    """Forget earlier stop requests (a new command starts)."""
    _stop_requests.clear()


def stop_requested():
    """The pending stop request (an exception), or None."""
    return _stop_requests[0] if _stop_requests else None


def check_stop():
    """Raise the pending stop request, if any."""
    if _stop_requests:
        raise _stop_requests[0]
