"""RMPTree: built modules arranged as a tree, evaluating RMPfusion's policy.

The tree knows its shape (``TreeLayout``) and its modules, nothing of YAML or registries: ``build/`` turns
a validated spec into both.

Forward pass: pushforward from the root to the leaves. Backward pass: pullback* from the leaves to the
root. Then resolve. Gradients reach every weight-function parameter, including through the h_i terms.
"""
from __future__ import annotations

import logging
import types
import warnings
from collections import Counter
from dataclasses import dataclass
from typing import Any, Mapping

import torch
from torch import Tensor, nn

from .algebra import Edge, NodeRMP, lu_solve, pullback_star, resolve
from .auxstate import AuxDict


@dataclass(frozen=True)
class NodeLabel:
    """What a node is made of, by registered name, for messages and ``describe``: map, weight, leaf RMP."""

    map: str
    weight: str | None = None  # a weight type, or ``shared:<name>`` for a shared weight
    rmp: str | None = None


@dataclass(frozen=True)
class TreeLayout:
    """The shape of a tree: root name and dimension, the aux state it reads, each node's parent (in declaration
    order) and what it is made of."""

    root: str
    dim: int
    aux_dims: Mapping[str, int]
    parents: Mapping[str, str]
    labels: Mapping[str, NodeLabel]


@dataclass
class TreeOutput:
    """The root's RMP and monitoring quantities for a batch of states."""

    qdd: Tensor
    f: Tensor
    M: Tensor
    G: Tensor
    B: Tensor
    Phi: Tensor
    V: Tensor
    L: Tensor
    nodes: dict[str, Any] | None = None  # per-node states and RMPs when asked for


def breadth_first(children: Mapping[str, list[str]], root: str) -> list[str]:
    """Every node below ``root``, parents before children: the pushforward order (reversed: pullback*)."""
    order, frontier = [], [root]
    while frontier:
        frontier = [c for p in frontier for c in children.get(p, [])]
        order += frontier
    return order


class NumericalError(FloatingPointError):
    """A non-finite value in a tree evaluation; the message names where it first appeared.

    ``where`` is that place (``q``, ``aux['goal']``, ``weight at node 'o1'``, ...) and ``samples`` the batch
    indices affected there (None when unknown), so a caller can isolate those samples and keep the others.
    """

    def __init__(self, message: str, where: str | None = None, samples: list[int] | None = None):
        super().__init__(message)
        diagnosis = message if isinstance(message, _Diagnosis) else None
        self.where = where if where is not None or diagnosis is None else diagnosis.where
        self.samples = samples if samples is not None or diagnosis is None else diagnosis.samples


class _Diagnosis(str):
    """A diagnosis message that also carries where and which samples (read by NumericalError)."""

    where: str | None = None
    samples: list[int] | None = None

    @classmethod
    def make(cls, text: str, where: str | None = None, samples: list[int] | None = None) -> "_Diagnosis":
        d = cls(text)
        d.where, d.samples = where, samples
        return d


def _nonfinite_samples(t: Tensor) -> list[int]:
    """Batch indices of the samples of ``t`` holding a non-finite value (all of them for an unbatched t)."""
    bad = ~torch.isfinite(t.detach())
    if bad.dim() == 0:
        return []
    return bad.reshape(bad.shape[0], -1).any(-1).nonzero().flatten().tolist()


def _samples_text(samples: list[int]) -> str:
    if not samples:
        return ""
    shown = ", ".join(map(str, samples[:10])) + (", …" if len(samples) > 10 else "")
    return f" in sample{'s' if len(samples) > 1 else ''} {shown}"


def _first_nonfinite(named) -> str | None:
    for name, t in named:
        if t is not None and not bool(torch.isfinite(t).all()):
            return name
    return None


class CompileFallbackWarning(RuntimeWarning):
    """A compiled tree met a construct torch.compile cannot trace and fell back (static shapes, then eager)."""


class BoundWeight(nn.Module):
    """A (possibly shared) weight function as seen from one edge: aux inputs renamed by ``bind``."""

    def __init__(self, fn: nn.Module, bind: Mapping[str, str] | None = None):
        super().__init__()
        self.fn = fn
        self.bind = dict(bind or {})

    @property
    def is_constant(self) -> bool:
        return bool(self.fn.is_constant)

    def forward(self, x: Tensor, aux: AuxDict | None):
        if self.bind and aux is not None:
            aux = {**aux, **{k: aux[v] for k, v in self.bind.items()}}
        return self.fn(x, aux)


class RMPTree(nn.Module):
    """An RMP-tree*: ``tree(q, qd, aux)`` returns the root's qdd, f, M, G, B, Phi, V (and L)."""

    def __init__(self, layout: TreeLayout, maps, weights, rmps, shared, resolve_method: str = "solve",
                 check_finite: bool = True):
        super().__init__()
        self.layout = layout
        self.root_name = layout.root
        self.dim = layout.dim
        self.aux_dims = dict(layout.aux_dims)
        self.maps = nn.ModuleDict(maps)
        self.weights = nn.ModuleDict(weights)
        self.rmps = nn.ModuleDict(rmps)
        self.shared = nn.ModuleDict(shared)
        self.resolve_method = resolve_method
        self.check_finite = check_finite  # a NaN must never become a command silently
        self.resolve_events: Counter = Counter()  # resolve's fallbacks met by this tree, in samples
        self.children_of: dict[str, list[str]] = {self.root_name: []}
        for n in layout.parents:
            self.children_of[n] = []
        for n, parent in layout.parents.items():
            self.children_of[parent].append(n)
        self.order = breadth_first(self.children_of, self.root_name)
        self.parent_of = dict(layout.parents)
        self.node_dims = {self.root_name: self.dim, **{n: maps[n].out_dim for n in layout.parents}}
        first: dict[tuple, str] = {}
        for n in self.order:  # maps that share a computation also share its modules
            key = self.maps[n].shared_key
            if key is not None:
                k = (self.parent_of[n], key)
                if k in first:
                    self.maps[n].adopt_shared(self.maps[first[k]])
                else:
                    first[k] = n
        self._compiled = None  # the torch.compile'd _root_rmp, built on first use after compile()
        self._compile_args: tuple | None = None
        self._dtype_cache: tuple | None = None  # (dtype,) once known; see _dtype

    def _normalise_aux(self, aux: AuxDict | None, batch: int, dtype: torch.dtype | None = None) -> dict[str, Tensor] | None:
        """Declared aux as (batch, dim) tensors; Python numbers become tensors of ``dtype`` (the state's; default
        the tree's), never of torch's default dtype, so a float64 tree gets its aux in float64."""
        if aux is None:
            return None
        out = dict(aux)
        for name, d in self.aux_dims.items():
            if name not in out:
                continue
            t = out[name]
            if not isinstance(t, Tensor):
                t = torch.as_tensor(t, dtype=dtype or self._dtype() or torch.get_default_dtype())
            if t.dim() == 1 and d == 1 and t.shape[0] == batch:
                t = t.unsqueeze(-1)
            elif t.dim() == 1:
                t = t.unsqueeze(0)
            if t.shape[-1] != d:
                raise ValueError(f"aux '{name}' has trailing dimension {t.shape[-1]}, the tree declares {d}")
            out[name] = t.expand(batch, d) if t.shape[0] == 1 else t
        return out

    def forward(self, q: Tensor, qd: Tensor, aux: AuxDict | None = None, return_nodes: bool = False) -> TreeOutput:
        if q.dim() != 2 or q.shape[-1] != self.dim or qd.shape != q.shape:
            raise ValueError(f"q and qd must both be (B, {self.dim}); got {tuple(q.shape)} and {tuple(qd.shape)}")
        dtype = self._dtype()
        if dtype is not None and (q.dtype != dtype or qd.dtype != dtype):
            raise TypeError(f"q and qd are {q.dtype} and {qd.dtype} but the tree computes in {dtype}; convert the "
                            f"state (q.to({dtype})) or the tree (tree.to({q.dtype}))")
        aux = self._normalise_aux(aux, q.shape[0], q.dtype)
        solved = False  # LU solve succeeded with a finite result for every sample
        if return_nodes:
            state, edges, rmp = self._passes(q, qd, aux)
            r = rmp[self.root_name]
        else:
            *fields, qdd, ok = self._root_rmp_maybe_compiled(q, qd, aux)
            r = NodeRMP(*fields)
            solved = self.resolve_method == "solve" and bool(ok)
        if not solved:  # singular or non-finite samples, or pinv asked for: the full treatment
            qdd = resolve(r.f, r.M, self.resolve_method, self.resolve_events)
        if self.check_finite and not solved and not bool(torch.isfinite(qdd).all()):
            raise NumericalError(self._diagnose(q, qd, aux))
        nodes = {"state": state, "edge": edges, "rmp": rmp} if return_nodes else None
        return TreeOutput(qdd=qdd, f=r.f, M=r.M, G=r.G, B=r.B, Phi=r.Phi, V=r.V, L=r.L, nodes=nodes)

    def _dtype(self) -> torch.dtype | None:
        """The floating dtype of the tree's parameters and buffers (float64 unless converted); None if it has none.
        Cached: walking the modules costs more than a compiled evaluation; ``.to()``/``.double()`` reset it."""
        if self._dtype_cache is None:
            found = [t.dtype for t in (*self.parameters(), *self.buffers()) if t.is_floating_point()]
            self._dtype_cache = (found[0] if found else None,)
        return self._dtype_cache[0]

    def _apply(self, fn, *args, **kwargs):
        self._dtype_cache = None
        return super()._apply(fn, *args, **kwargs)

    def _passes(self, q: Tensor, qd: Tensor, aux: dict[str, Tensor] | None):
        """Pushforward then pullback*: every node's state, edge and RMP (the root's RMP under the root's name).

        Sibling maps that declare the same ``shared_key`` (e.g. forward kinematics of one robot to several
        links) compute their common part once per parent state through ``prepare``.
        """
        state = {self.root_name: (q, qd)}
        edges: dict[str, Edge] = {}
        prepared: dict[tuple, Any] = {}
        for n in self.order:  # pushforward
            parent = self.parent_of[n]
            x, xd = state[parent]
            m = self.maps[n]
            key = m.shared_key
            if key is None:
                y, yd, J, c = m(x, xd, aux)
            else:
                if (parent, key) not in prepared:
                    prepared[(parent, key)] = m.prepare(x, xd, aux)
                y, yd, J, c = m.from_prepared(prepared[(parent, key)], x, xd, aux)
            w = gw = None
            if n in self.weights:
                w, gw = self.weights[n](x, aux)
            state[n] = (y, yd)
            edges[n] = Edge(J=J, c=c, yd=yd, w=w, grad_w=gw, identity=m.identity_jacobian)
        rmp: dict[str, NodeRMP] = {}
        for n in reversed(self.order):  # pullback*
            kids = self.children_of[n]
            if kids:
                rmp[n] = pullback_star(state[n][1], ((edges[k], rmp[k]) for k in kids))
            else:
                rmp[n] = self.rmps[n](*state[n])
        rmp[self.root_name] = pullback_star(qd, ((edges[k], rmp[k]) for k in self.children_of[self.root_name]))
        return state, edges, rmp

    def _root_rmp(self, q: Tensor, qd: Tensor, aux: dict[str, Tensor] | None) -> tuple[Tensor, ...]:
        """The root's RMP, its LU-solved acceleration and whether that solve is good for every sample, as a
        plain tuple of tensors: the pure tensor program that ``compile`` hands to torch.compile."""
        r = self._passes(q, qd, aux)[2][self.root_name]
        a, good = lu_solve(r.M, r.f)
        return r.f, r.M, r.G, r.B, r.Phi, r.L, r.V, a, good.all()

    def compile(self, dynamic: bool | None = None, options: dict[str, Any] | None = None,
                fixed_structure: bool = False) -> "RMPTree":
        """Evaluate through ``torch.compile`` (same code, fused kernels): pays off for small batches in a
        control loop and for training. The first call per input shape compiles (seconds to minutes);
        inductor caches the result on disk for later processes. ``return_nodes`` and the checks stay eager.
        Copies of a compiled tree (``copy.deepcopy``) compile their own code on their first call.

        ``fixed_structure=True`` is for a controller whose tree no longer changes: the compiled call skips its
        checks that the tree's modules and their settings are unchanged (about 0.3 ms of a 1.1 ms Franka call
        at B = 1). Parameters stay inputs, so loading or training new weights is seen; changing a module or a
        non-parameter setting after the first call is not (call ``compile`` again)."""
        opts = {"cpp_wrapper": True, **(options or {})}  # C++ call wrapper: less Python per call
        if fixed_structure:
            opts.setdefault("guard_filter_fn", torch.compiler.skip_guard_on_all_nn_modules_unsafe)
        self._compile_args = (dynamic, opts)
        self._compiled = None
        return self

    def _compiled_fn(self):
        if self._compiled is None:
            dynamic, options = self._compile_args
            # the C++ wrapper calls LU ops through a generic shim and says so at every compile: expected
            logging.getLogger("torch._inductor.ir").setLevel(logging.ERROR)
            # a construct that cannot be traced is reported once by the fallback, not by torch's tracer logs
            logging.getLogger("torch._subclasses.fake_tensor").setLevel(logging.CRITICAL)
            # inductor's own use of a deprecated torch helper warns at every compile: not the user's concern
            warnings.filterwarnings("ignore", message=r".*torch\._prims_common\.check.*", category=FutureWarning)
            # a private copy of the function's code: torch.compile caches per code object, so trees compiled in one
            # process would otherwise pile their guards onto one cache and each call would check all of them
            fn = types.FunctionType(RMPTree._root_rmp.__code__.replace(), globals(), f"_root_rmp_{id(self):x}")
            self._compiled = torch.compile(types.MethodType(fn, self), dynamic=dynamic, options=options)
        return self._compiled

    def _root_rmp_maybe_compiled(self, q: Tensor, qd: Tensor, aux: dict[str, Tensor] | None) -> tuple[Tensor, ...]:
        """``_root_rmp`` through the compiled code when the tree is compiled. A construct torch.compile cannot
        trace never crashes the tree: with a symbolic batch size (forward-mode autodiff, e.g. a leaf whose
        curvature is derived by ``torch.func.jvp``) the tree compiles again per batch size; if that fails too it
        runs eagerly. Each step is said once (``CompileFallbackWarning``); the numbers are the same."""
        while self._compile_args is not None:
            try:
                return self._compiled_fn()(q, qd, aux)
            except torch._dynamo.exc.TorchDynamoException as e:
                self._fall_back(e)
        return self._root_rmp(q, qd, aux)

    def _fall_back(self, error: Exception) -> None:
        dynamic, options = self._compile_args
        reason = str(error).strip().splitlines()[0][:200] if str(error).strip() else type(error).__name__
        if dynamic is not False:
            self._compile_args, self._compiled = (False, options), None
            warnings.warn(CompileFallbackWarning(
                "torch.compile cannot trace this tree with a symbolic batch size, typically because of forward-mode "
                f"autodiff (a map's or leaf's derivatives left to the defaults) ({reason}); it now compiles once per "
                "batch size (static shapes), with the same numbers"), stacklevel=6)
        else:
            self.uncompile()
            warnings.warn(CompileFallbackWarning(
                f"torch.compile cannot compile this tree ({reason}); it now runs eagerly, with the same numbers"),
                stacklevel=6)

    def uncompile(self) -> "RMPTree":
        self._compiled = self._compile_args = None
        return self

    def __getstate__(self):
        # copies and pickles carry the tree and whether it is compiled, not the compiled code (bound to this tree)
        state = super().__getstate__() if hasattr(super(), "__getstate__") else self.__dict__.copy()
        return {**state, "_compiled": None}

    def _diagnose(self, q: Tensor, qd: Tensor, aux: AuxDict | None) -> str:
        """Where the first non-finite value came from: inputs, then nodes in pushforward order, then the leaves'
        and inner nodes' RMPs, then the root. The message names the place and the samples; the returned string
        also carries them as ``where`` and ``samples`` for ``NumericalError``."""
        declared = [k for k in (aux or {}) if k in self.aux_dims]  # aux the tree does not use cannot be the cause
        inputs = [("q", q), ("qd", qd), *((f"aux['{k}']", aux[k]) for k in declared)]
        bad = _first_nonfinite(inputs)
        if bad:
            samples = _nonfinite_samples(dict(inputs)[bad])
            return _Diagnosis.make(f"non-finite input {bad}{_samples_text(samples)}; check the state or aux state "
                                   "passed to the tree (a NaN here must not become a command)", bad, samples)

        def scale() -> str:  # finite but extreme inputs overflow inside the tree: say how large they were
            big = [f"max |{n}| = {float(t.detach().abs().max()):.3g}" for n, t in (("q", q), ("qd", qd)) if t.numel()]
            return "; inputs were finite (" + ", ".join(big) + ")"

        was, self.check_finite = self.check_finite, False
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the fallback was already reported by the failing call
                out = self.forward(q, qd, aux, return_nodes=True)
        finally:
            self.check_finite = was
        n = out.nodes
        for name in self.order:
            e = n["edge"][name]
            named = [("y", n["state"][name][0]), ("ydot", n["state"][name][1]), ("J", e.J), ("Jdot_xdot", e.c),
                     ("weight", e.w), ("weight gradient", e.grad_w)]
            where = _first_nonfinite(named)
            if where:
                samples = _nonfinite_samples(dict(named)[where])
                label = self.layout.labels[name]
                origin = f"weight {label.weight}" if where.startswith("weight") else f"map {label.map}"
                return _Diagnosis.make(f"non-finite {where} at node '{name}' ({origin}){_samples_text(samples)}{scale()}",
                                       f"{where} at node '{name}'", samples)
        for name in reversed(self.order):
            items = list(n["rmp"][name].items())
            where = _first_nonfinite(items)
            if where:
                samples = _nonfinite_samples(dict(items)[where])
                rmp = self.layout.labels[name].rmp
                kind = f"leaf {rmp}" if rmp else "pullback* of its children"
                return _Diagnosis.make(f"non-finite {where} in the RMP of node '{name}' ({kind}){_samples_text(samples)}"
                                       f"{scale()}", f"{where} in the RMP of node '{name}'", samples)
        items = list(n["rmp"][self.root_name].items())
        where = _first_nonfinite(items)
        if where:
            samples = _nonfinite_samples(dict(items)[where])
            return _Diagnosis.make(f"non-finite root {where} after pullback*{_samples_text(samples)}{scale()}",
                                   f"root {where}", samples)
        samples = _nonfinite_samples(out.qdd)
        return _Diagnosis.make(
            f"non-finite acceleration from resolve{_samples_text(samples)}: the root inertia M is singular or badly "
            "conditioned there; add an identity_metric leaf on the root", "resolve", samples)

    def policy(self, q: Tensor, qd: Tensor, aux: AuxDict | None = None) -> Tensor:
        """Just the acceleration: the closed loop q̈ = π(q, q̇)."""
        return self.forward(q, qd, aux).qdd

    def describe(self) -> str:
        """The tree drawn as text: node, dimension, map, weight, rmp."""
        lines = [f"{self.root_name} (dim {self.dim})"]

        def label(n: str) -> str:
            node = self.layout.labels[n]
            parts = [f"{n} (dim {self.node_dims[n]})", f"map={node.map}"]
            if node.weight is not None:
                parts.append(f"weight={node.weight}")
            if node.rmp is not None:
                parts.append(f"rmp={node.rmp}")
            return "  ".join(parts)

        def walk(p: str, prefix: str) -> None:
            kids = self.children_of[p]
            for i, k in enumerate(kids):
                last = i == len(kids) - 1
                lines.append(f"{prefix}{'└── ' if last else '├── '}{label(k)}")
                walk(k, prefix + ("    " if last else "│   "))

        walk(self.root_name, "")
        return "\n".join(lines)
