"""``state_file`` persistence of the monitor node: restore at configuration, atomic save on request and at the end.

The file is ``{"node": <full name>, "saved_unix_s": <time>, "pipeline": MonitorPipeline.get_state()}``. A file
refused at start (other model, rate or corrupt) is never overwritten; this run's state is saved beside it
(``<stem>.<UTC time>.json``).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
from std_srvs.srv import Trigger

from ..config import MonitorConfig
from ..core.monitor.pipeline import MonitorPipeline, PipelineError
from .channel import ChannelContext, ChannelCore


def beside(path: str) -> str:
    """Where this run saves when ``path`` was refused: ``<stem>.<UTC time>.json`` next to it (never ``path``)."""
    p = Path(path)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    out = p.with_name(f"{p.stem}.{stamp}.json")
    k = 1
    while out.exists():
        out = p.with_name(f"{p.stem}.{stamp}-{k}.json")
        k += 1
    return str(out)


def write_atomic(path: str, text: str) -> None:
    """Write ``text`` to ``path`` so that it is either the old or the complete new file (temp, fsync, replace)."""
    d = os.path.dirname(os.path.abspath(path))
    tmp = os.path.join(d, f".{os.path.basename(path)}.tmp{os.getpid()}")
    try:
        with open(tmp, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


class StateStore:
    """Restore and save of the pipeline state, and the reset, rebaseline and save_state services (a part of
    :class:`.channel_parts.ChannelParts`)."""

    def __init__(self, ctx: ChannelContext, core: ChannelCore) -> None:
        self.ctx = ctx
        self.core = core
        self.save_path = ""                # where save_state writes ("" -> the state_file parameter)

    def restore(self, cfg: MonitorConfig, state_file: str) -> MonitorPipeline | None:
        """The pipeline restored from ``state_file``, or None. A refused file (corrupt, another node's fully
        qualified name, other K, rate, controller, delay, loop or structures) is kept untouched: this run saves
        beside it (one log line)."""
        self.save_path = state_file
        if not state_file or not Path(state_file).exists():
            return None
        try:
            saved = json.loads(Path(state_file).read_text())
            node = str(saved.get("node", ""))
            if node and node != self.ctx.name:
                raise PipelineError(f"written by node {node}, this node is {self.ctx.name}")
            pipeline = MonitorPipeline(cfg, state=saved["pipeline"])
        except (OSError, ValueError, KeyError, TypeError, PipelineError) as exc:
            reason = str(exc) if isinstance(exc, PipelineError) else f"unreadable: {type(exc).__name__}: {exc}"
            self.save_path = beside(state_file)
            self.ctx.logger.warning(f"state file {state_file} refused ({reason}); starting fresh, the file is "
                                      f"kept unchanged and this run's state will be saved to {self.save_path}")
            return None
        self.ctx.logger.info(f"state restored from {state_file} (estimating: {pipeline.initialized})")
        self._memory_from_parameter(pipeline)
        return pipeline

    def _memory_from_parameter(self, pipeline: MonitorPipeline) -> None:
        """The parameter ``modes.memory_s`` is the one owner of the memories: a state saved after a runtime change
        restores the estimate, and the memories the parameter gives apply from here on (one log line)."""
        if pipeline.K == 0:
            return
        wanted = np.array([m.memory_s for m in pipeline.cfg.modes], dtype=float)
        if np.array_equal(wanted, pipeline.memory_s):
            return
        saved = pipeline.memory_s.tolist()
        pipeline.update_params({"modes.memory_s": wanted.tolist()})
        self.ctx.logger.info(f"the state was saved with modes.memory_s={saved}; the parameter's {wanted.tolist()} "
                             "applies (runtime parameter changes are not saved: set them in the params file)")

    def save_state(self) -> str:
        """Write the pipeline state atomically (temp file, fsync, ``os.replace``) to ``state_file`` or, when
        that file was refused at start, beside it; returns a one-line result."""
        path = self.save_path if self.core.pipeline is not None else self.ctx.parameter("state_file")
        if not path:
            return "state_file is empty: nothing saved"
        with self.core.lock:
            if self.core.pipeline is None:
                return "not configured: nothing saved"
            doc = {"node": self.ctx.name, "saved_unix_s": time.time(),
                   "pipeline": self.core.pipeline.get_state()}
        write_atomic(path, json.dumps(doc))
        self.ctx.logger.info(f"state saved to {path}")
        return f"state saved to {path}"

    # ------------------------------------------------------------------------------------ services
    def srv_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self.core.lock:
            if self.core.pipeline is None:
                response.success, response.message = False, "not configured"
                return response
            self.core.pipeline.reset()
            sync = self.core.configured_sync()
            sync.resync(time.monotonic_ns(), "reset requested", count=False)
            sync.set_time_floor(None)
        response.success, response.message = True, "estimator, baseline and fault state reset"
        return response

    def srv_rebaseline(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        with self.core.lock:
            if self.core.pipeline is None:
                response.success, response.message = False, "not configured"
                return response
            closed = self.core.pipeline.rebaseline()
        response.success = True
        response.message = f"learning a new baseline; {len(closed)} open fault event(s) closed"
        return response

    def srv_save(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        path = self.ctx.parameter("state_file")
        if not path:
            response.success, response.message = False, "parameter state_file is empty"
            return response
        try:
            response.message = self.save_state()
            response.success = True
        except OSError as exc:
            response.success, response.message = False, f"cannot write {path}: {exc}"
        return response
