"""The node's last words on ``/rosout``: the one-line fatal error and the stop notice that ``rsrivc_monitor`` prints to
stderr (its exit contract: one line, no log prefix) also reach ``/rosout`` (rqt_console, log recorders), as the
node's other log lines do.

They are published as ``rcl_interfaces/msg/Log`` under the node's logger name with rosout's own QoS (reliable,
transient local, 10 s lifespan), not through the logger, which would print the line a second time. The process
ends right after, so :func:`publish_last_words` waits briefly for a ``/rosout`` reader to be discovered and to
acknowledge (a late-joining reader gets it from the transient-local history while the node is still there).
"""

from __future__ import annotations

import inspect
import time
from typing import Any

from rcl_interfaces.msg import Log
from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

ROSOUT = "/rosout"
#: rcl's rosout profile (rcl/logging_rosout.h: keep last 1000, reliable, transient local, lifespan 10 s)
ROSOUT_QOS = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL, lifespan=Duration(seconds=10))
def one_line_error(exc: BaseException) -> str:
    """How ``rsrivc_monitor`` words a fatal error: a ParamError as it is, anything else with its type."""
    from ..config import ParamError

    return str(exc) if isinstance(exc, ParamError) else f"{type(exc).__name__}: {exc}"


#: how long a fatal error waits for /rosout readers to be discovered and to acknowledge it before the process ends
#: (with 1 s a listening test missed it in 2 of 3 runs on a loaded 2-core machine, with 3 s in none of 5; no
#: reader at all: the full wait)
FATAL_WAIT_S = 3.0
LEVELS = {"debug": Log.DEBUG, "info": Log.INFO, "warn": Log.WARN, "error": Log.ERROR, "fatal": Log.FATAL}


def last_words_publisher(node: Any) -> Any:
    """A /rosout publisher of ``node``, created when the node is (so that it is matched by the time it is used)."""
    return node.create_publisher(Log, ROSOUT, ROSOUT_QOS)


def publish_last_words(node: Any, pub: Any, level: str, text: str, *, wait_s: float = FATAL_WAIT_S) -> bool:
    """Publish ``text`` at ``level`` (debug/info/warn/error/fatal) on /rosout through ``pub`` as ``node``'s logger;
    wait up to ``wait_s`` for a reader to match and acknowledge. True when a reader acknowledged it (False: none was
    there, or it could not be published; never raises: the caller is exiting)."""
    if pub is None:
        return False
    try:
        caller = inspect.stack(0)[1]
        msg = Log(level=LEVELS[level], name=node.get_logger().name, msg=text, file=caller.filename,
                  function=caller.function, line=caller.lineno)
        msg.stamp = node.get_clock().now().to_msg()
        pub.publish(msg)
        t_end = time.monotonic() + wait_s
        while True:
            if pub.get_subscription_count() > 0 and pub.wait_for_all_acked(Duration(seconds=0.1)):
                return True
            if time.monotonic() >= t_end:
                return False
            time.sleep(0.02)
    except Exception:  # noqa: BLE001 - the context may already be shut down
        return False
