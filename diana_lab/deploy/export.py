"""Torch side of the deployment: a trained SB3 policy -> ``policy.onnx`` + ``policy.json`` (the sidecar).

The graph holds everything between the observation and the waypoint offset, so that the runtime cannot
get any of it subtly wrong:

1. VecNormalize observation normalisation, ``clip((x - mean) / sqrt(var + eps), -clip_obs, clip_obs)``,
   with the training run's statistics baked in as constants (only the keys it normalised);
2. the features extractor and the actor, deterministic (the Gaussian mean; ``tanh`` of it for squashed
   actors such as SAC/TD3/TQC; the argmax of the logits for a categorical policy, ``action_space=discrete``);
3. SB3's ``predict`` post-processing (unscale a squashed action, else clip to the action space) and the env's
   clip to [-1, 1] (continuous actions only);
4. the action -> waypoint-offset mapping of :class:`diana_lab.envs.action_spaces.WaypointMapping` (square or
   Shirley-Chiu disc, scaled, ``min_distance`` push-out; or a gather from the discrete candidate table) in
   the ACTION frame. Turning it by the yaw (``frame=rover``) and adding the position is left to the runtime,
   in float64 numpy.

Inputs ``goal`` ``(B, 7)`` and the encoding ``(B, ...)`` (batch dynamic); outputs ``offset`` ``(B, 2)`` and
``action``: ``(B, 2)``, or for a discrete policy the chosen candidate's index ``(B,)`` (int64) and its
``logits`` ``(B, n)`` (the slope shield's ranking; the index is their argmax). So the runtime, which reads
only ``offset`` unless the sidecar carries a ``shield``, is the same for every action space. Opsets from 18 go
through torch's current exporter (``dynamo=True``, with onnxscript); older ones, the default 17 included (what
TensorRT 8.6 on JetPack 5/6 parses), through its TorchScript-based one (``dynamo=False``), see
:func:`exporter_for`. The sidecar's ``source.exporter`` names the one used. The TorchScript exporter cannot export
an adaptive average pool whose output does not divide its input (the paper's 112 x 112 camera), so every
``AdaptiveAvgPool2d`` is replaced by the same average written as two constant matrix products (for both).

Importing this module imports torch; :mod:`diana_lab.deploy` itself never does.
"""

from __future__ import annotations

import contextlib
import copy
import datetime as dt
import logging
import math
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from torch import nn

from diana_lab.config import ConfigError
from diana_lab.config.env import ActionSpaceConfig, EpisodeConfig
from diana_lab.config.sensing import SensorConfig
from diana_lab.core.candidates import candidate_offsets
from diana_lab.deploy.sidecar import action_spec, expected_shape, observation_statistics, policy_spec
from diana_lab.deploy.spec import ActionSpec, PolicySpec, sidecar_path

__all__ = [
    "DEFAULT_OPSET",
    "ExportablePolicy",
    "check_opset",
    "check_output",
    "export_policy",
    "exporter_for",
    "opset_range",
]

DEFAULT_OPSET = 17  # what onnxruntime >= 1.14 and TensorRT 8.6 (JetPack 5/6) both run
# torch's dynamo exporter writes opset 18 and up; for less it runs onnx's version converter, which leaves the strips and
# points graphs at 18 and gives the categorical head an opset-18 ReduceLogSumExp that the checker refuses at 17: those
# opsets (the default among them) keep the TorchScript exporter
DYNAMO_MIN_OPSET = 18
VERIFY_TOLERANCE = 1e-4  # metres: ONNX vs torch on random observations, checked at every export
# a discrete policy's argmax at logits closer than this may fall either way between torch and onnxruntime
# (float rounding); such near-ties are left out of the export check
LOGIT_TIE = 1e-4
LOGIT_TOLERANCE = 1e-3  # a discrete graph's logits against torch's, relative beyond 1 (the shield ranks by them)


# ---------------------------------------------------------------------------------------------- graph parts
def _pool_matrix(n_in: int, n_out: int) -> torch.Tensor:
    """``(n_out, n_in)`` averaging weights of PyTorch's adaptive pooling (bins floor(i n/m) .. ceil((i+1) n/m))."""
    m = torch.zeros(n_out, n_in)
    for i in range(n_out):
        start, end = (i * n_in) // n_out, -((-(i + 1) * n_in) // n_out)
        m[i, start:end] = 1.0 / (end - start)
    return m


class MatmulAdaptiveAvgPool2d(nn.Module):
    """``AdaptiveAvgPool2d`` for one fixed input size as ``rows @ x @ cols^T`` (exportable for any size)."""

    def __init__(self, in_hw: tuple[int, int], out_hw: tuple[int, int]) -> None:
        super().__init__()
        self.register_buffer("rows", _pool_matrix(in_hw[0], out_hw[0]))
        self.register_buffer("cols_t", _pool_matrix(in_hw[1], out_hw[1]).T.contiguous())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.matmul(torch.matmul(self.rows, x), self.cols_t)


def _replace_adaptive_pools(module: nn.Module, example: dict[str, torch.Tensor], run: Any) -> None:
    """Swap every ``AdaptiveAvgPool2d`` in ``module`` for its matmul form, sized by one forward pass."""
    sizes: dict[str, tuple[int, int]] = {}
    hooks = []
    for name, sub in module.named_modules():
        if isinstance(sub, nn.AdaptiveAvgPool2d):
            hooks.append(
                sub.register_forward_pre_hook(
                    lambda _m, args, name=name: sizes.__setitem__(name, tuple(args[0].shape[-2:]))
                )
            )
    with torch.no_grad():
        run(example)
    for h in hooks:
        h.remove()
    for name, (h, w) in sizes.items():
        parent_name, _, child = name.rpartition(".")
        parent = module.get_submodule(parent_name) if parent_name else module
        pool = getattr(parent, child)
        out = pool.output_size if isinstance(pool.output_size, tuple | list) else (pool.output_size,) * 2
        out_hw = (h if out[0] is None else int(out[0]), w if out[1] is None else int(out[1]))
        setattr(parent, child, MatmulAdaptiveAvgPool2d((h, w), out_hw))


def square_to_disc(a: torch.Tensor) -> torch.Tensor:
    """Torch twin of :func:`diana_lab.envs.action_spaces.square_to_disc` for ``(B, 2)`` actions."""
    x, y = a[:, 0], a[:, 1]
    one = torch.ones_like(x)
    use_x = x.abs() > y.abs()
    safe_x = torch.where(x == 0, one, x)
    safe_y = torch.where(y == 0, one, y)
    r = torch.where(use_x, x, y)
    q = math.pi / 4.0
    theta = torch.where(use_x, q * (y / safe_x), math.pi / 2 - q * (x / safe_y))
    theta = torch.where((x == 0) & (y == 0), torch.zeros_like(x), theta)
    return torch.stack([r * torch.cos(theta), r * torch.sin(theta)], dim=-1)


class ExportablePolicy(nn.Module):
    """``(goal, encoding) -> (offset, action)``: normalisation, deterministic actor, clipping, mapping."""

    def __init__(
        self,
        policy: nn.Module,
        sensor_key: str,
        normalization: dict[str, tuple[np.ndarray, np.ndarray]],
        clip_obs: float,
        action: ActionSpec,
    ) -> None:
        super().__init__()
        self.policy = policy
        self.sensor_key = sensor_key
        self.keys = ("goal", sensor_key)
        self.norm_keys = tuple(k for k in self.keys if k in normalization)
        for key in self.norm_keys:
            mean, std = normalization[key]
            self.register_buffer(f"mean_{key}", torch.as_tensor(mean, dtype=torch.float32))
            self.register_buffer(f"std_{key}", torch.as_tensor(std, dtype=torch.float32))
        self.clip_obs = float(clip_obs)
        space = policy.action_space
        self.discrete = isinstance(space, spaces.Discrete)
        if self.discrete:  # row k: the offset of action k, as WaypointMapping.candidates
            table = candidate_offsets(int(action.headings), tuple(action.distances))
            self.register_buffer("candidates", torch.as_tensor(table, dtype=torch.float32))
        else:
            self.register_buffer("low", torch.as_tensor(space.low, dtype=torch.float32))
            self.register_buffer("high", torch.as_tensor(space.high, dtype=torch.float32))
        self.squash = bool(policy.squash_output)
        self.action = action

    def normalized(self, obs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        out = dict(obs)
        for key in self.norm_keys:
            x = (obs[key] - getattr(self, f"mean_{key}")) / getattr(self, f"std_{key}")
            out[key] = torch.clamp(x, -self.clip_obs, self.clip_obs)
        return out

    def logits(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """A categorical policy's ``(B, n)`` action logits (the export check's near-tie test)."""
        return self.policy.get_distribution(self.normalized(obs)).distribution.logits

    def actor(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        """The deterministic action as ``model.predict`` returns it: a discrete policy's candidate index
        ``(B,)``, else ``(B, 2)`` after the env's clip to [-1, 1]."""
        if self.discrete:
            return self.policy._predict(self.normalized(obs), deterministic=True).reshape(-1)
        a = self.policy._predict(self.normalized(obs), deterministic=True).reshape(-1, 2)
        if self.squash:
            a = self.low + 0.5 * (a + 1.0) * (self.high - self.low)  # BasePolicy.unscale_action
        else:
            a = torch.maximum(torch.minimum(a, self.high), self.low)
        return torch.clamp(a, -1.0, 1.0)

    def mapping(self, a: torch.Tensor) -> torch.Tensor:
        """Action -> offset in the action frame (``WaypointMapping.offset`` without the yaw rotation)."""
        if self.discrete:
            return self.candidates[a]  # ONNX Gather
        local = (square_to_disc(a) if self.action.shape == "circle" else a) * self.action.extent
        d = self.action.min_distance
        if d > 0:
            norm = torch.sqrt(torch.sum(local * local, dim=-1, keepdim=True))
            forward = torch.tensor([[1.0, 0.0]], dtype=local.dtype).expand_as(local)
            unit = torch.where(norm > 1e-9, local / torch.clamp(norm, min=1e-12), forward)
            local = torch.where(norm < d, unit * d, local)
        return local

    def forward(self, goal: torch.Tensor, encoding: torch.Tensor) -> tuple[torch.Tensor, ...]:
        obs = {"goal": goal, self.sensor_key: encoding}
        if self.discrete:  # the logits too (the slope shield ranks the candidates by them), from one pass
            logits = self.logits(obs)
            a = torch.argmax(logits, dim=-1)
            return self.mapping(a), a, logits
        a = self.actor(obs)
        return self.mapping(a), a


# ---------------------------------------------------------------------------------------------- export
def _check_action(model: Any, action: ActionSpaceConfig, label: str) -> None:
    """The model's action space must be the one ``action`` describes (a (2,) Box, or as many candidates)."""
    space = model.action_space
    if isinstance(space, spaces.Discrete):
        n = action.headings * len(action.distances) if action.shape == "discrete" else None
        if n != space.n:
            given = f"{n} candidates" if n is not None else f"action_space.shape={action.shape}"
            raise ConfigError(
                f"policy {label}: a categorical policy over {space.n} candidates, but the action_space config "
                f"gives {given}; export with the action_space it was trained with"
            )
        return
    if tuple(space.shape) != (2,):
        raise ConfigError(f"policy {label}: expected a (2,) action, got {space.shape}")
    if action.shape == "discrete":
        raise ConfigError(
            f"policy {label}: a continuous (2,) action, but action_space.shape=discrete; export with the "
            "action_space it was trained with"
        )


def _check_model(model: Any, sensor: SensorConfig, label: str) -> str:
    """The model's sensor key, after checking it is exportable and fits ``sensor`` (naming what differs)."""
    policy = getattr(model, "policy", None)
    if policy is None or not hasattr(policy, "_predict"):
        raise ConfigError(f"policy {label}: {type(model).__name__} has no SB3 policy to export")
    if "lstm" in type(policy).__name__.lower() or hasattr(policy, "lstm_actor"):
        raise ConfigError(
            f"policy {label}: recurrent policies need their hidden state carried between calls; "
            "exporting them is not supported"
        )
    space = model.observation_space
    keys = sorted(getattr(space, "spaces", {}))
    if "goal" not in keys or len(keys) != 2:
        raise ConfigError(f"policy {label}: expected a Dict observation of 'goal' and one sensor key, got {keys}")
    key = next(k for k in keys if k != "goal")
    want = expected_shape(sensor)
    got = tuple(space[key].shape)
    if key != sensor.encoding or got != want:
        raise ConfigError(
            f"policy {label}: observes '{key}' {got}, but the sensor config gives "
            f"'{sensor.encoding}' {want}; export with the sensor settings it was trained with"
        )
    return key


@contextlib.contextmanager
def _quiet_export() -> Iterator[None]:
    """No distribution argument checks (data-dependent branches break tracing) and no exporter chatter (warnings,
    and the dynamo exporter's log records, e.g. that torchvision's ops are skipped)."""
    validate = torch.distributions.Distribution._validate_args
    torch.distributions.Distribution.set_default_validate_args(False)
    log = logging.getLogger("torch.onnx")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        log.setLevel(level)
        torch.distributions.Distribution.set_default_validate_args(validate)


def _export_graph(
    graph: nn.Module, example: tuple[torch.Tensor, ...], output: Path, opset: int, inputs: list[str], outputs: list[str]
) -> None:
    """Write ``graph`` to ``output`` at ``opset`` through :func:`exporter_for`'s exporter, batch dynamic; refuse a
    graph at another opset than asked (the sidecar records it)."""
    import onnx

    options: dict[str, Any] = {"dynamo": False}
    if exporter_for(opset) == "dynamo":  # one file, weights inside; no progress lines; onnxscript's graph optimiser
        options = {"dynamo": True, "external_data": False, "verbose": False, "optimize": True}
    with _quiet_export(), torch.no_grad():
        torch.onnx.export(
            graph,
            example,
            str(output),
            input_names=inputs,
            output_names=outputs,
            opset_version=opset,
            dynamic_axes={n: {0: "batch"} for n in (*inputs, *outputs)},
            **options,
        )
    imports = onnx.load(str(output), load_external_data=False).opset_import
    got = next((o.version for o in imports if o.domain in ("", "ai.onnx")), None)
    if got != opset:
        raise RuntimeError(f"the {exporter_for(opset)} exporter wrote opset {got}, not {opset}")


def _samples(model: Any, key: str, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    space = model.observation_space
    rng = np.random.default_rng(seed)

    def draw(box: Any) -> np.ndarray:
        low, high = np.broadcast_to(box.low, box.shape), np.broadcast_to(box.high, box.shape)
        return rng.uniform(low, high, (n, *box.shape)).astype(np.float32)

    return draw(space["goal"]), draw(space[key])


def _decisive(reference: ExportablePolicy, goal: np.ndarray, enc: np.ndarray, key: str) -> np.ndarray:
    """The sample rows the export check compares: all of them, except (for a discrete policy) near-ties of
    its two largest logits, where float rounding may pick either candidate in either runtime."""
    if not reference.discrete:
        return np.ones(len(goal), dtype=bool)
    with torch.no_grad():
        top = torch.topk(reference.logits({"goal": torch.from_numpy(goal), key: torch.from_numpy(enc)}), 2).values
    return (top[:, 0] - top[:, 1]).numpy() >= LOGIT_TIE


def exporter_for(opset: int) -> str:
    """``"dynamo"`` (torch's current exporter) from :data:`DYNAMO_MIN_OPSET` on, else ``"torchscript"``."""
    return "dynamo" if opset >= DYNAMO_MIN_OPSET else "torchscript"


def opset_range() -> tuple[int, int]:
    """The opsets torch's exporters support: from the TorchScript one's least (below, it writes graphs the onnx
    checker refuses) to the dynamo one's most, capped by what the installed onnx knows."""
    import onnx
    from torch.onnx import _constants

    return int(_constants.ONNX_MIN_OPSET), min(int(_constants.ONNX_MAX_OPSET), int(onnx.defs.onnx_opset_version()))


def check_opset(opset: int) -> None:
    """Refuse an opset outside :func:`opset_range` before anything is exported (naming ``opset``)."""
    from diana_lab.errors import UserError

    low, high = opset_range()
    if not low <= opset <= high:
        raise UserError(
            f"opset={opset}: expected an ONNX opset from {low} to {high} (what torch {torch.__version__}'s exporters "
            f"and the installed onnx support); the default, {DEFAULT_OPSET}, runs on onnxruntime >= 1.14 and "
            "TensorRT 8.6"
        )


def check_output(output: Path) -> None:
    """Refuse an ``output`` whose sidecar (the same name with ``.json``) would be the graph's own file: the
    sidecar, written last, would replace the graph."""
    from diana_lab.errors import UserError

    if output.suffix.lower() == ".json":
        raise UserError(
            f"output={output}: the sidecar goes next to the graph with the suffix .json, i.e. to this same file; "
            f"expected the graph's path, e.g. output={output.with_suffix('.onnx')} (the sidecar then goes to "
            f"{output.with_suffix('.json').name})"
        )


def export_policy(
    model: Any,
    vecnormalize: Any,
    sensor: SensorConfig,
    action: ActionSpaceConfig,
    episode: EpisodeConfig,
    output: str | Path,
    opset: int = DEFAULT_OPSET,
    source: dict[str, Any] | None = None,
    shield: dict[str, Any] | None = None,
) -> PolicySpec:
    """Write ``output`` (ONNX) and its sidecar; check the graph against torch on random observations.
    ``shield``: the slope shield's settings (``ShieldSettings`` as a dict) for the sidecar; a discrete policy
    only (the runtime ranks its candidates by the graph's ``logits``)."""
    import onnx
    import onnxruntime as ort

    output = Path(output)
    check_output(output)
    check_opset(opset)
    label = str((source or {}).get("label", "model"))
    key = _check_model(model, sensor, label)
    _check_action(model, action, label)
    if shield is not None and action.shape != "discrete":
        raise ConfigError(
            f"policy {label}: eval.shield.enabled with action_space.shape={action.shape}: the slope shield ranks a "
            "discrete policy's candidates; export with eval.shield.enabled=false"
        )
    act = action_spec(action)
    norm, clip_obs = observation_statistics(vecnormalize, ("goal", key))
    policy = model.policy
    policy.set_training_mode(False)
    reference = ExportablePolicy(policy, key, norm, clip_obs, act).eval()
    graph = ExportablePolicy(copy.deepcopy(policy), key, norm, clip_obs, act).eval()
    goal0, enc0 = _samples(model, key, 1)
    with _quiet_export():
        _replace_adaptive_pools(
            graph.policy, {"goal": torch.from_numpy(goal0), key: torch.from_numpy(enc0)}, graph.actor
        )
    output.parent.mkdir(parents=True, exist_ok=True)
    outputs = ["offset", "action", "logits"] if graph.discrete else ["offset", "action"]
    goal, enc = _samples(model, key, 16, seed=1)
    try:
        example = (torch.from_numpy(goal0), torch.from_numpy(enc0))
        _export_graph(graph, example, output, opset, ["goal", key], outputs)
        onnx.checker.check_model(str(output))
        session = ort.InferenceSession(str(output), providers=["CPUExecutionProvider"])
        got = session.run(outputs, {"goal": goal, key: enc})
    except Exception as exc:
        output.unlink(missing_ok=True)  # never leave a graph behind that failed its check or cannot run
        if opset == DEFAULT_OPSET:  # the tested opset: a bug, whose traceback is wanted
            raise
        from diana_lab.errors import UserError

        why = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise UserError(
            f"opset={opset}: this policy's graph could not be exported, checked and run at opset {opset} ({why}); "
            f"nothing was written. Expected an opset its operators exist in: the default, {DEFAULT_OPSET}, is tested"
        ) from exc
    with torch.no_grad():
        want = [t.numpy() for t in reference(torch.from_numpy(goal), torch.from_numpy(enc))]
    decisive = _decisive(reference, goal, enc, key)
    err = float(np.max(np.abs(got[0] - want[0])[decisive], initial=0.0))
    logit_err = 0.0
    if graph.discrete:  # relative beyond 1: a planner head's logits reach ~1e6 (banned candidates)
        logit_err = float(np.max(np.abs(got[2] - want[2]) / np.maximum(1.0, np.abs(want[2])), initial=0.0))
    if not logit_err <= LOGIT_TOLERANCE:
        output.unlink(missing_ok=True)
        raise RuntimeError(
            f"export: the ONNX graph's logits differ from the torch policy's by {logit_err:.2e} (relative) on random "
            f"observations (tolerance {LOGIT_TOLERANCE}); nothing was written"
        )
    if not err <= VERIFY_TOLERANCE:
        output.unlink(missing_ok=True)  # never leave a graph on disk that would drive differently
        raise RuntimeError(
            f"export: the ONNX graph differs from the torch policy by {err:.2e} m on random "
            f"observations (tolerance {VERIFY_TOLERANCE}); nothing was written"
        )
    normalization = {"baked_into_graph": True, "keys": sorted(norm), "clip_obs": clip_obs if norm else None}
    src = {
        **(source or {}),
        "algorithm": type(model).__name__,
        "torch": torch.__version__,
        "exporter": exporter_for(opset),  # torch.onnx.export(dynamo=True) or the TorchScript-based one
        "exported_at": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "export_check_max_error_m": err,
        **({"export_check_max_logit_error": logit_err} if graph.discrete else {}),
    }
    spec = policy_spec(model, sensor, action, episode, normalization, src, opset, shield)
    spec.save(sidecar_path(output))
    return spec
