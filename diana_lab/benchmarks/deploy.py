"""Deployment figures: the policy's inference latency in the ONNX runtime of ``diana_lab/deploy``.

That runtime does not exist yet, so :func:`policy_latency` reports both keys as null with a note. When it
lands, this function is the only thing to write: export a freshly built PPO policy (``train_fps_ppo`` shows
how to build one), load it in the deploy runtime, and time single observations (batch 1, one thread) over
``ctx.size(5000, 500)`` calls per repeat with :func:`~diana_lab.benchmarks.core.repeat`; report the p50 and
p99 of the per-call latencies (not of the per-repeat medians: p99 is a tail figure).
"""

from __future__ import annotations

import importlib.util

from diana_lab.benchmarks.core import BenchContext, Figure, measurement

__all__ = ["policy_latency"]

MISSING_NOTE = "not measured: the deployment runtime (diana_lab/deploy, ONNX) does not exist yet"


@measurement("policy_latency_ms_p50", "policy_latency_ms_p99")
def policy_latency(ctx: BenchContext) -> list[Figure]:
    del ctx
    note = MISSING_NOTE
    if importlib.util.find_spec("diana_lab.deploy") is not None:
        note = "not measured: diana_lab/deploy exists now; write diana_lab/benchmarks/deploy.py:policy_latency"
    return [Figure(key, "ms", None, note=note) for key in ("policy_latency_ms_p50", "policy_latency_ms_p99")]
