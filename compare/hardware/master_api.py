"""The two calls of the ROS master API the bridge makes itself, with a timeout (no ROS import).

* :func:`master_online` — ``getPid``: does a master answer at the URI;
* :func:`topic_publishers` — ``getSystemState``: who publishes on which topic, by caller id.

rospy's own master proxy has no timeout; these calls never wait longer than asked.
"""

from __future__ import annotations

import xmlrpc.client
from typing import Any

from compare.hardware.exceptions import HardwareError

PROBE_CALLER_ID = "/tpik_compare_probe"
"""Caller id of the calls made before this node exists."""


class MasterCallFailed(HardwareError):
    """The master did not answer a call, or answered with an error or an unexpected value."""


class _TimeoutTransport(xmlrpc.client.Transport):
    def __init__(self, timeout_s: float) -> None:
        super().__init__()
        self._timeout_s = timeout_s

    def make_connection(self, host: Any) -> Any:
        conn = super().make_connection(host)
        conn.timeout = self._timeout_s
        return conn


def _proxy(uri: str, timeout_s: float) -> xmlrpc.client.ServerProxy:
    return xmlrpc.client.ServerProxy(uri, transport=_TimeoutTransport(timeout_s))


def master_online(uri: str, timeout_s: float = 1.0) -> bool:
    """Whether a ROS master answers ``getPid`` at ``uri`` within ``timeout_s``."""
    try:
        code, _, _ = _proxy(uri, timeout_s).getPid(PROBE_CALLER_ID)
        return int(code) == 1
    except (TimeoutError, OSError, xmlrpc.client.Error, ValueError, TypeError):
        return False


def topic_publishers(uri: str, caller_id: str, timeout_s: float) -> dict[str, tuple[str, ...]]:
    """Topic → caller ids of its publishers, as the master knows them (``getSystemState``).

    Raises:
        MasterCallFailed: no answer within ``timeout_s``, an error code, or a malformed answer.
    """
    try:
        code, message, state = _proxy(uri, timeout_s).getSystemState(caller_id)
    except (TimeoutError, OSError, xmlrpc.client.Error, ValueError, TypeError) as exc:
        raise MasterCallFailed(f"getSystemState at {uri}: {exc}") from None
    if code != 1:
        raise MasterCallFailed(f"getSystemState at {uri}: code {code} ({message})")
    try:
        publishers = state[0]
        return {str(topic): tuple(str(n) for n in nodes) for topic, nodes in publishers}
    except (TypeError, ValueError, IndexError) as exc:
        raise MasterCallFailed(f"getSystemState at {uri}: unexpected answer ({exc})") from None
