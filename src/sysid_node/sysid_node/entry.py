"""Entry point of the ``sysid_node`` executable: clean start-up and shutdown under any signals.

``ros2 launch`` forwards a Ctrl-C as SIGINT and, while the node stops, may send another one,
then SIGTERM; a terminal sends SIGINT to the whole process group, the worker included. So:

- SIGINT and SIGTERM only set a flag, from the first instant this module runs (the 10-20 s of
  imports on a busy machine included); rclpy is initialised without its own signal handlers;
- the executor spins in short slices and checks the flag; a stop request during start-up ends
  the run as soon as the current import or the worker's start returns;
- the worker process ignores SIGINT (the node stops it);
- exit status 0 after a requested stop, 1 after a start-up error; never a traceback.
"""

from __future__ import annotations

import _signal  # built in, already loaded: the handlers go in before any slower import

_requests: list[int] = []


def _on_signal(signum: int, _frame: object) -> None:
    _requests.append(signum)


# at import (the console script imports this module before calling main): a Ctrl-C during the
# rest of the start-up is a stop request, not a KeyboardInterrupt in the middle of an import
try:
    for _sig in (_signal.SIGINT, _signal.SIGTERM):
        _signal.signal(_sig, _on_signal)
except ValueError:  # imported outside the main thread: main() installs them
    pass

import signal  # noqa: E402
import sys  # noqa: E402


def stop_requested() -> bool:
    return bool(_requests)


def install() -> None:
    """Catch SIGINT and SIGTERM as stop requests (main thread only)."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)


def main(args: list[str] | None = None) -> int:
    install()
    try:
        return _run(args)
    except KeyboardInterrupt:  # only if a handler was replaced behind our back
        return 0
    finally:
        # exiting now: Python's finalization would restore the default actions, and a late
        # SIGTERM (launch escalating) would then kill the process with status -15
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)


def _run(args: list[str] | None) -> int:
    # hand the GIL over often, so subscriptions are served while the receiver publishes
    sys.setswitchinterval(0.001)
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from sysid_node.node import StartupError, SysidNode

    if stop_requested():
        return 0
    from sysid_node import params as P
    from sysid_node import params_file as PF

    files, name = PF.files_in_args(sys.argv if args is None else args)
    try:  # what rcl would ignore silently or answer with a traceback
        for f in files:
            PF.node_values(PF.read(f), name or "sysid_node", P.SPECS, path=f)
    except PF.ParamsFileError as err:
        return _fail(err)
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as err:  # RCLError: bad --ros-args, unparseable parameter file
        return _fail(err)
    node = None
    code = 0
    try:
        try:
            node = SysidNode(cancelled=stop_requested)
        except StartupError:
            raise
        except Exception as err:  # RCLError from rcl (parameter overrides, names)
            raise StartupError(_one_line(err)) from None
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        while not stop_requested() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    except StartupError as err:
        if not stop_requested():
            print(f"sysid_node: error: {err}", file=sys.stderr, flush=True)
            code = 1
    finally:
        if node is not None:
            node.stop()
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def _one_line(err: BaseException) -> str:
    lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
    return lines[0] if lines else type(err).__name__


def _fail(err: BaseException) -> int:
    print(f"sysid_node: error: {_one_line(err)}", file=sys.stderr, flush=True)
    return 1


if __name__ == "__main__":
    sys.exit(main())
