"""Densification primitives on ``Expert.splats`` that keep the optimiser state in step.

Every op replaces each per-Gaussian tensor by a new ``nn.Parameter`` and applies the same row
operation to the tensors of the optimiser state (Adam ``exp_avg``, ``exp_avg_sq``, ...); the scalar
``step`` count is kept. As in 3DGS, a replaced parameter has no ``.grad``, so an optimiser step
taken right after an op leaves it unchanged for that iteration.

``params`` is the ``ParameterDict`` (raw values: log-scales, opacity logits, ...); ``optimizers``
maps a key of ``params`` to the optimiser holding it (``Optimizers.for_splats``); keys without an
optimiser (e.g. a non-trainable model index) are updated without state.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

from moegs.render.projection import covariance_3d, quat_to_rotmat

Rows = Callable[[str, Tensor], Tensor]


@torch.no_grad()
def update_params(
    params: nn.ParameterDict,
    optimizers: dict[str, torch.optim.Optimizer],
    param_fn: Rows,
    state_fn: Rows,
    keys: list[str] | None = None,
) -> None:
    """Replace ``params[key]`` by ``param_fn(key, value)`` and each row-indexed optimiser state
    tensor ``v`` by ``state_fn(key, v)``, for every key (or the given ``keys``)."""
    for key in list(params.keys()) if keys is None else keys:
        old = params[key]
        new = nn.Parameter(param_fn(key, old.detach()), requires_grad=old.requires_grad)
        params[key] = new
        opt = optimizers.get(key)
        if opt is None:
            continue
        for group in opt.param_groups:
            for i, p in enumerate(group["params"]):
                if p is not old:
                    continue
                group["params"][i] = new
                state = opt.state.pop(old, None)
                if state:
                    opt.state[new] = {
                        k: state_fn(key, v)
                        if isinstance(v, Tensor) and v.ndim > 0 and v.shape[0] == old.shape[0]
                        else v
                        for k, v in state.items()
                    }


def _append_zero_moments(new_rows: int) -> Rows:
    def fn(key: str, v: Tensor) -> Tensor:
        return torch.cat([v, v.new_zeros((new_rows, *v.shape[1:]))])

    return fn


@torch.no_grad()
def append(params: nn.ParameterDict, optimizers: dict, rows: dict[str, Tensor]) -> None:
    """Append new Gaussians: ``rows[key] [M, ...]`` for every key of ``params``; new moments are zero."""
    if set(rows) != set(params.keys()):
        raise KeyError(f"append needs rows for exactly {sorted(params.keys())}, got {sorted(rows)}")
    m = {v.shape[0] for v in rows.values()}
    if len(m) != 1:
        raise ValueError(f"append: rows of different lengths {sorted(m)}")
    update_params(
        params, optimizers, lambda k, v: torch.cat([v, rows[k].to(v)]), _append_zero_moments(m.pop())
    )


@torch.no_grad()
def duplicate(params: nn.ParameterDict, optimizers: dict, mask: Tensor) -> None:
    """Append a copy of the Gaussians selected by ``mask [N]`` (3DGS clone); new moments are zero."""
    index = mask.nonzero(as_tuple=True)[0]
    update_params(params, optimizers, lambda k, v: torch.cat([v, v[index]]), _append_zero_moments(len(index)))


@torch.no_grad()
def split(
    params: nn.ParameterDict, optimizers: dict, mask: Tensor, samples: int = 2, scale_divisor: float = 1.6
) -> None:
    """3DGS split: each selected Gaussian is replaced by ``samples`` children.

    Children are centred at points drawn from the parent (``mean + R diag(s) eps``, ``eps ~ N(0, I)``)
    with scales ``s / scale_divisor`` (3DGS: ``0.8 * N`` = 1.6 for N = 2) and the parent's other
    parameters; they are appended after the unselected Gaussians with zero moments.

    Args:
        mask: ``[N]`` bool, the Gaussians to split.
    """
    index = mask.nonzero(as_tuple=True)[0]
    keep = torch.nonzero_static(~mask, size=mask.shape[0] - index.shape[0])[:, 0]
    scales = torch.exp(params["scales"][index])  # [M, 3]
    rotmats = quat_to_rotmat(nn.functional.normalize(params["quats"][index], dim=-1))  # [M, 3, 3]
    noise = torch.randn(samples, len(index), 3, device=scales.device) * scales  # [S, M, 3]
    offsets = torch.einsum("mij,smj->smi", rotmats, noise).reshape(-1, 3)  # [S*M, 3]

    def children(key: str, v: Tensor) -> Tensor:
        parents = v[index]
        if key == "means":
            kids = parents.repeat(samples, 1) + offsets
        elif key == "scales":
            kids = torch.log(scales / scale_divisor).repeat(samples, 1)
        else:
            kids = parents.repeat(samples, *([1] * (v.ndim - 1)))
        return torch.cat([v[keep], kids])

    def moments(key: str, v: Tensor) -> Tensor:
        return torch.cat([v[keep], v.new_zeros((samples * len(index), *v.shape[1:]))])

    update_params(params, optimizers, children, moments)


@torch.no_grad()
def remove(params: nn.ParameterDict, optimizers: dict, mask: Tensor) -> None:
    """Delete the Gaussians selected by ``mask [N]`` and their optimiser rows."""
    keep = (~mask).nonzero(as_tuple=True)[0]
    update_params(params, optimizers, lambda k, v: v[keep], lambda k, v: v[keep])


@torch.no_grad()
def reset_opacity(params: nn.ParameterDict, optimizers: dict, value: float) -> None:
    """3DGS opacity reset: ``opacity = min(opacity, value)``; the opacity moments are zeroed."""
    cap = torch.logit(torch.tensor(value, device="cpu")).item()
    update_params(
        params,
        optimizers,
        lambda k, v: v.clamp(max=cap),
        lambda k, v: torch.zeros_like(v),
        keys=["opacities"],
    )


def _with_new_source_values(
    key: str, v: Tensor, sources: Tensor, opacities: Tensor, scales: Tensor
) -> Tensor:
    """A copy of parameter ``key``'s rows ``v`` with the MCMC sources' new raw opacity and scale written."""
    v = v.clone()
    if key == "opacities":
        v[sources] = opacities
    elif key == "scales":
        v[sources] = scales
    return v


def _zeroed_rows(v: Tensor, rows: Tensor) -> Tensor:
    """A copy of the optimizer moments ``v`` with ``rows`` zeroed."""
    v = v.clone()
    v[rows] = 0
    return v


@torch.no_grad()
def relocate(
    params: nn.ParameterDict,
    optimizers: dict,
    dead: Tensor,
    sources: Tensor,
    opacities: Tensor,
    scales: Tensor,
) -> None:
    """3DGS-MCMC relocation: ``dead [D]`` slots copy ``sources [D]``; both get the new raw values.

    Args:
        dead: indices of the Gaussians to overwrite.
        sources: index of the live Gaussian each dead one copies (repetitions allowed).
        opacities: new opacity logits of the sources ``[D]`` (aligned with ``sources``).
        scales: new log-scales of the sources ``[D, 3]``.

    The sources' moments are zeroed (as in 3DGS-MCMC ``replace_tensors_to_optimizer(inds=...)``); the
    dead slots keep theirs, as in the original.
    """

    def rows(key: str, v: Tensor) -> Tensor:
        v = _with_new_source_values(key, v, sources, opacities, scales)
        v[dead] = v[sources]
        return v

    def moments(key: str, v: Tensor) -> Tensor:
        return _zeroed_rows(v, sources)

    update_params(params, optimizers, rows, moments)


@torch.no_grad()
def sample_add(
    params: nn.ParameterDict, optimizers: dict, sources: Tensor, opacities: Tensor, scales: Tensor
) -> None:
    """3DGS-MCMC growth: append copies of ``sources [A]``; sources and copies get the new raw values.

    ``opacities [A]`` / ``scales [A, 3]`` are the new raw values aligned with ``sources``. The copies
    get zero moments and the sources' moments are zeroed (3DGS-MCMC ``add_new_gs``).
    """

    def rows(key: str, v: Tensor) -> Tensor:
        v = _with_new_source_values(key, v, sources, opacities, scales)
        return torch.cat([v, v[sources]])

    def moments(key: str, v: Tensor) -> Tensor:
        return torch.cat([_zeroed_rows(v, sources), v.new_zeros((len(sources), *v.shape[1:]))])

    update_params(params, optimizers, rows, moments)


@torch.no_grad()
def inject_noise(params: nn.ParameterDict, scale: Tensor) -> None:
    """3DGS-MCMC SGLD step: ``means += scale * Sigma @ eps`` in place, ``Sigma = R S² Rᵀ``.

    Args:
        scale: ``[N]`` per-Gaussian factor (``noise_lr * lr_means * gate(opacity)``).
    """
    covars = covariance_3d(nn.functional.normalize(params["quats"], dim=-1), torch.exp(params["scales"]))
    eps = torch.randn_like(params["means"]) * scale[:, None]
    params["means"].add_((covars @ eps[:, :, None])[:, :, 0])
