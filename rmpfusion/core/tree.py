"""RMPTree: built modules arranged as a tree, evaluating RMPfusion's policy.

The tree knows its shape (``TreeLayout``) and its modules, nothing of YAML or registries: ``assembly/`` turns
a validated spec into both.

Evaluation is level-batched (docs/math.md §9): the tree plans once which nodes evaluate together
(``core/groups.py``: nodes of one kind under one parent group), then runs pushforward from the root to the leaves
and pullback* from the leaves to the root group by group (``core/passes.py``), then resolve. Gradients reach every
weight-function parameter, including through the h_i terms.
"""

from __future__ import annotations

import logging
import types
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import torch
from torch import Tensor, nn

from .algebra import Edge, NodeRMP, lu_solve, resolve
from .auxstate import AuxDict, AuxSource
from .diagnosis import NumericalError, bad_input, bad_node
from .gds import LeafRMP
from .groups import Plan
from .groups import plan as plan_tree
from .layout import NodeLabel, TreeLayout, breadth_first  # noqa: F401  (re-exported: assembly/ and tests use them here)
from .passes import Passes, evaluate
from .taskmap import TaskMap
from .weight import BoundWeight

M = TypeVar("M", bound=nn.Module)

# The root's RMP (f, M, G, B, Φ, L, V; G to V None when lean), its LU-solved acceleration and whether that solve is
# good for every sample: what the (compiled) evaluation of a tree returns.
RootTuple = tuple[
    Tensor, Tensor, Tensor | None, Tensor | None, Tensor | None, Tensor | None, Tensor | None, Tensor, Tensor
]


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

    def to(self, device: torch.device | str) -> TreeOutput:
        """The root's quantities on ``device`` (per-node ones are left where they are)."""
        moved = {k: getattr(self, k).to(device) for k in ("qdd", "f", "M", "G", "B", "Phi", "V", "L")}
        return TreeOutput(**moved, nodes=self.nodes)


class CompileFallbackWarning(RuntimeWarning):
    """A compiled tree met a construct torch.compile cannot trace and fell back (static shapes, then eager)."""


def _forget_groups(module: RMPTree, incompatible_keys) -> None:
    """After a state dict is loaded: constants stacked into the groups may have changed, plan them again."""
    module._plan = None


def _of_kind(modules: nn.ModuleDict, kind: type[M]) -> dict[str, M]:
    """A tree's modules of one kind (task maps, bound weights, leaves: ``assembly/`` builds them so), by node."""
    out: dict[str, M] = {}
    for name, module in modules.items():
        assert isinstance(module, kind), f"node '{name}' holds a {type(module).__name__}, not a {kind.__name__}"
        out[name] = module
    return out


class RMPTree(nn.Module):
    """An RMP-tree*: ``tree(q, qd, aux)`` returns the root's qdd, f, M, G, B, Phi, V (and L)."""

    def __init__(
        self, layout: TreeLayout, maps, weights, rmps, shared, resolve_method: str = "solve", check_finite: bool = True
    ):
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
        self.children_of = layout.children()
        self.order = breadth_first(self.children_of, self.root_name)
        self.parent_of = dict(layout.parents)
        self.node_dims = {self.root_name: self.dim, **{n: maps[n].out_dim for n in layout.parents}}
        self._plan: Plan | None = None  # planned on first use; again after .to() or a loaded state dict
        self.register_load_state_dict_post_hook(_forget_groups)
        self._compiled = None  # the torch.compile'd _root_rmp, built on first use after compile()
        self._compile_args: tuple[bool | None, dict[str, Any]] | None = None  # (dynamic, options) once compiled
        self._dtype_cache: tuple | None = None  # (dtype,) once known; see _dtype
        self.aux_source: AuxSource | None = None  # makes declared aux from the caller's inputs; see read_aux_through
        self.compile_failure: str | None = None  # why torch.compile could not compile the tree, once it fell back

    @property
    def plan(self) -> Plan:
        """Which nodes and weights evaluate together (``core/groups.py``), for the tree's current device and dtype."""
        if self._plan is None:
            like = torch.empty(0, dtype=self._dtype() or torch.float64, device=self.device)
            maps, weights = _of_kind(self.maps, TaskMap), _of_kind(self.weights, BoundWeight)
            self._plan = plan_tree(self.layout, maps, weights, _of_kind(self.rmps, LeafRMP), like)
        return self._plan

    def _normalise_aux(
        self, aux: AuxDict | None, batch: int, dtype: torch.dtype | None = None
    ) -> dict[str, Tensor] | None:
        """Declared aux as (batch, dim) tensors; Python numbers become tensors of ``dtype`` (the state's; default
        the tree's), never of torch's default dtype, so a float64 tree gets its aux in float64."""
        if aux is None:
            return None
        out = dict(aux)
        for name, t in aux.items():  # what was given (a tree fed by an aux source declares many it is not given)
            if name not in self.aux_dims:
                continue
            d = self.aux_dims[name]
            if isinstance(t, Tensor) and t.shape == (batch, d):  # already as the tree takes it: the common case
                continue
            if not isinstance(t, Tensor):
                t = torch.as_tensor(t, dtype=dtype or self._dtype() or torch.get_default_dtype())
            if t.dim() == 1 and d == 1 and t.shape[0] == batch:
                t = t.unsqueeze(-1)
            elif t.dim() == 1:
                t = t.unsqueeze(0)
            if t.shape[-1] != d:
                raise ValueError(f"aux '{name}' has trailing dimension {t.shape[-1]}, the tree declares {d}")
            if t.dim() != 2 or t.shape[0] not in (1, batch):
                raise ValueError(
                    f"aux '{name}' has shape {tuple(t.shape)} but q holds {batch} states; give it one row "
                    f"per state, ({batch}, {d}), or one row for them all, (1, {d})"
                )
            out[name] = t.expand(batch, d) if t.shape[0] == 1 else t
        return out

    def read_aux_through(self, source: AuxSource | None) -> RMPTree:
        """Call the tree with ``source.inputs`` in place of the aux entries ``source`` makes (``AuxSource``): the
        entries are made inside every evaluation, compiled with it. None: the caller passes every entry again."""
        self.aux_source = source
        self._compiled = None  # traced again: the evaluation now starts with the source
        return self

    def aux_with_source(self, q: Tensor, aux: AuxDict | None) -> AuxDict | None:
        """The aux state with the source's entries made (the aux as given when the tree has no source)."""
        if self.aux_source is None or aux is None:
            return aux
        return {**aux, **self.aux_source(q, aux)}

    def _source_inputs(self, aux: dict[str, Tensor] | None, batch: int) -> dict[str, Tensor] | None:
        """The source's inputs checked (present, per-sample shapes) and broadcast to the batch."""
        if self.aux_source is None:
            return aux
        out = dict(aux or {})
        for name, shape in self.aux_source.inputs.items():
            if name not in out:
                raise KeyError(f"aux '{name}' of shape (B, {', '.join(map(str, shape))}) is required by this tree")
            t = out[name]
            if tuple(t.shape[1:]) != tuple(shape) or t.shape[0] not in (1, batch):
                raise ValueError(
                    f"aux '{name}' must be ({batch} or 1, {', '.join(map(str, shape))}); got {tuple(t.shape)}"
                )
            out[name] = t.expand(batch, *shape)
        return out

    def _inputs(self, q: Tensor, qd: Tensor, aux: AuxDict | None) -> dict[str, Tensor] | None:
        """The state checked (shapes, the tree's dtype) and the aux state normalised; the tree planned."""
        if q.dim() != 2 or q.shape[-1] != self.dim or qd.shape != q.shape:
            raise ValueError(f"q and qd must both be (B, {self.dim}); got {tuple(q.shape)} and {tuple(qd.shape)}")
        dtype = self._dtype()
        if dtype is not None and (q.dtype != dtype or qd.dtype != dtype):
            raise TypeError(
                f"q and qd are {q.dtype} and {qd.dtype} but the tree computes in {dtype}; convert the "
                f"state (q.to({dtype})) or the tree (tree.to({q.dtype}))"
            )
        _ = self.plan  # planned before any compiled code runs
        return self._source_inputs(self._normalise_aux(aux, q.shape[0], q.dtype), q.shape[0])

    def forward(self, q: Tensor, qd: Tensor, aux: AuxDict | None = None, return_nodes: bool = False) -> TreeOutput:
        aux = self._inputs(q, qd, aux)
        nodes = None
        ok: Tensor | bool = False  # the LU solve succeeded with a finite result for every sample
        qdd: Tensor | None = None
        if return_nodes:
            passes = evaluate(self.plan, q, qd, self.aux_with_source(q, aux))
            r, nodes = passes.root, self._per_node(passes)
        else:
            f, M, G, B, Phi, L, V, qdd, ok = self._root_rmp_maybe_compiled(q, qd, aux, False)
            r = NodeRMP(f, M, G, B, Phi, L, V)
        qdd = self._resolved(q, qd, aux, r.f, r.M, qdd, ok)
        G, B, Phi, L, V = r.monitored()
        return TreeOutput(qdd=qdd, f=r.f, M=r.M, G=G, B=B, Phi=Phi, V=V, L=L, nodes=nodes)

    def overdamped_field(self, q: Tensor, aux: AuxDict | None = None) -> Tensor:
        """v(q) = B_r⁻¹ f_r(q, 0) = −B_r⁻¹ ∇Φ_r (B, d): the velocity the tree's motion follows where its damping
        dominates its inertia, a first-order field every tree with B_r ≻ 0 carries.

        At q̇ = 0 every curvature term and every damping force vanishes and pullback* leaves f_r = −∇_q Σ W_i Φ_i
        (the weights' gradients included, docs/math.md §12), so one evaluation at rest gives it. Learning this field
        from recorded velocities fits the tree the way first-order learners are fitted (Euclideanizing flows: through
        a learned diffeomorphism with damping B it is the natural gradient descent −(JᵀBJ)⁻¹Jᵀ∇Φ), while the tree
        stays the second-order GDS it is, with Theorem 2 and its other leaves. Differentiable in the parameters.
        NaN in the rows where B_r is singular to working precision (a map that flattens space there): no field is
        defined, and callers that sample far from the data (train.speed_limit) leave those rows out."""
        out = self(q, torch.zeros_like(q), aux)
        _, defined = lu_solve(out.B.detach(), out.f.detach())  # the test resolve trusts a solve by
        eye = torch.eye(out.B.shape[-1], dtype=out.B.dtype, device=out.B.device)
        B = torch.where(defined[..., None, None], out.B, eye)  # no gradient flows through a singular solve
        v = torch.linalg.solve(B, out.f.unsqueeze(-1)).squeeze(-1)
        return torch.where(defined[..., None], v, torch.nan)

    def _resolved(
        self, q: Tensor, qd: Tensor, aux: AuxDict | None, f: Tensor, M: Tensor, qdd: Tensor | None, ok: Tensor | bool
    ) -> Tensor:
        """q̈: the LU answer when it is good for every sample, else resolve's of the root's (f, M) (pseudo-inverse
        where M is singular); a non-finite answer raises NumericalError naming where it came from."""
        if qdd is not None and self.resolve_method == "solve" and bool(ok):
            return qdd
        qdd = resolve(f, M, self.resolve_method, self.resolve_events)
        if self.check_finite and not bool(torch.isfinite(qdd).all()):
            raise NumericalError(self._diagnose(q, qd, self.aux_with_source(q, aux)))
        return qdd

    @property
    def device(self) -> torch.device:
        """Where the tree's parameters and buffers are (the CPU for a tree that has none)."""
        return next((t.device for t in (*self.parameters(), *self.buffers())), torch.device("cpu"))

    def _dtype(self) -> torch.dtype | None:
        """The floating dtype of the tree's parameters and buffers (float64 unless converted); None if it has none.
        Cached: walking the modules costs more than a compiled evaluation; ``.to()``/``.double()`` reset it."""
        if self._dtype_cache is None:
            found = [t.dtype for t in (*self.parameters(), *self.buffers()) if t.is_floating_point()]
            self._dtype_cache = (found[0] if found else None,)
        return self._dtype_cache[0]

    def _apply(self, fn, *args, **kwargs):
        self._dtype_cache = None
        self._plan = None  # stacked constants follow the modules to their new dtype or device
        return super()._apply(fn, *args, **kwargs)

    def _per_node(self, passes: Passes) -> dict[str, dict[str, Any]]:
        """Each node's state, edge and RMP (the root's RMP under the root's name), taken from its group's rows."""
        state: dict[str, tuple[Tensor, Tensor]] = {}
        edges: dict[str, Edge] = {}
        rmp: dict[str, NodeRMP] = {}
        for g, (y, yd), e, r in zip(self.plan.groups, passes.states, passes.edges, passes.rmps):
            for n, s in g.slots.items():
                state[n] = (y[s], yd[s])
                edges[n] = Edge(
                    J=e.J[s],
                    c=e.c[s],
                    yd=e.yd[s],
                    w=None if e.w is None else e.w[s],
                    grad_w=None if e.grad_w is None else e.grad_w[s],
                    identity=e.identity,
                )
                rmp[n] = r.map(_row(s))
        rmp[self.root_name] = passes.root
        return {"state": state, "edge": edges, "rmp": rmp}

    def _root_rmp(self, q: Tensor, qd: Tensor, aux: dict[str, Tensor] | None, lean: bool) -> RootTuple:
        """The root's RMP, its LU-solved acceleration and whether that solve is good for every sample, as a
        plain tuple of tensors: the pure tensor program that ``compile`` hands to torch.compile."""
        assert self._plan is not None, "planned by _inputs before any evaluation"
        r = evaluate(self._plan, q, qd, self.aux_with_source(q, aux), lean).root
        a, good = lu_solve(r.M, r.f)
        return r.f, r.M, r.G, r.B, r.Phi, r.L, r.V, a, good.all()

    def compile(  # type: ignore[override]  # not nn.Module.compile: compiles the evaluation, with its own options
        self,
        dynamic: bool | None = None,
        options: dict[str, Any] | None = None,
        fixed_structure: bool = False,
        vectorize: bool = True,
    ) -> RMPTree:
        """Evaluate through ``torch.compile`` (same code, fused kernels): pays off for small batches in a
        control loop and for training. The first call per input shape compiles (seconds to minutes);
        inductor caches the result on disk for later processes. ``return_nodes`` and the checks stay eager.
        Copies of a compiled tree (``copy.deepcopy``) compile their own code on their first call.

        ``fixed_structure=True`` is for a controller whose tree no longer changes: the compiled call skips its
        checks that the tree's modules and their settings are unchanged (about 0.3 ms of a 1.1 ms Franka call
        at B = 1). Parameters stay inputs, so loading or training new weights is seen; changing a module or a
        non-parameter setting after the first call is not (call ``compile`` again).

        ``vectorize=False`` is the single-state mode (B = 1, a controller): CPU code without SIMD loops (no lanes to
        fill; the compile takes about a third less time) called through inductor's C++ wrapper, which spends less
        Python per call but routes the matrix products through a generic shim that costs 2× at B = 4096
        (``make bench``).

        ``dynamic=False`` makes dynamo patch its config around every call (about a sixth of a compiled single-state
        call); a caller that keeps its batch size leaves ``dynamic`` None, whose first compile is static too."""
        opts = dict(options or {})
        if not vectorize:
            opts.setdefault("cpp.vec_isa_ok", False)
            opts.setdefault("cpp_wrapper", True)
        if fixed_structure:
            opts.setdefault("guard_filter_fn", torch.compiler.skip_guard_on_all_nn_modules_unsafe)
        self._compile_args = (dynamic, opts)
        self._compiled = None
        self.compile_failure = None
        return self

    @property
    def evaluation_mode(self) -> str:
        """How the tree evaluates: "compiled" (through torch.compile), "eager" (not asked to compile), or "eager
        (<why>)" where torch.compile could not compile it and the tree fell back (``CompileFallbackWarning``)."""
        if self._compile_args is not None:
            return "compiled"
        return "eager" if self.compile_failure is None else f"eager ({self.compile_failure})"

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

    def _root_rmp_maybe_compiled(self, q: Tensor, qd: Tensor, aux: dict[str, Tensor] | None, lean: bool) -> RootTuple:
        """``_root_rmp`` through the compiled code when the tree is compiled. A construct torch.compile cannot
        trace never crashes the tree: with a symbolic batch size (forward-mode autodiff, e.g. a leaf whose
        curvature is derived by ``torch.func.jvp``) the tree compiles again per batch size; if that fails too it
        runs eagerly. Each step is said once (``CompileFallbackWarning``); the numbers are the same."""
        while self._compile_args is not None:
            try:
                return self._compiled_fn()(q, qd, aux, lean)
            except torch._dynamo.exc.TorchDynamoException as e:
                self._fall_back(e)
        return self._root_rmp(q, qd, aux, lean)

    def _fall_back(self, error: Exception) -> None:
        assert self._compile_args is not None, "only a compiled tree falls back"
        dynamic, options = self._compile_args
        reason = _compile_failure(error)
        if dynamic is not False:
            self._compile_args, self._compiled = (False, options), None
            warnings.warn(
                CompileFallbackWarning(
                    "torch.compile cannot trace this tree with a symbolic batch size, typically because of forward-mode "
                    f"autodiff (a map's or leaf's derivatives left to the defaults) ({reason}); it now compiles once per "
                    "batch size (static shapes), with the same numbers"
                ),
                stacklevel=6,
            )
        else:
            self.uncompile()
            self.compile_failure = f"torch.compile cannot compile it: {reason}"
            warnings.warn(
                CompileFallbackWarning(
                    f"torch.compile cannot compile this tree ({reason}); it now runs eagerly, with the same numbers"
                ),
                stacklevel=6,
            )

    def uncompile(self) -> RMPTree:
        self._compiled = self._compile_args = None
        return self

    def __getstate__(self):
        # copies and pickles carry the tree and whether it is compiled, not the compiled code or the plan (bound to
        # this tree's modules: a copy plans its own)
        state = super().__getstate__() if hasattr(super(), "__getstate__") else self.__dict__.copy()
        return {**state, "_compiled": None, "_plan": None}

    def _diagnose(self, q: Tensor, qd: Tensor, aux: AuxDict | None) -> str:
        """Where the first non-finite value came from (``core/diagnosis.py``): inputs, then nodes in pushforward
        order, then the leaves' and inner nodes' RMPs, then the root, then resolve."""
        bad = bad_input(q, qd, aux, list(self.aux_dims))
        if bad is not None:
            return bad
        was, self.check_finite = self.check_finite, False
        try:
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the fallback was already reported by the failing call
                out = self.forward(q, qd, aux, return_nodes=True)
        finally:
            self.check_finite = was
        assert out.nodes is not None, "asked for with return_nodes"
        return bad_node(self.layout, self.order, out.nodes, out.qdd, q, qd)

    def policy(self, q: Tensor, qd: Tensor, aux: AuxDict | None = None) -> Tensor:
        """Just the acceleration: the closed loop q̈ = π(q, q̇). A tree none of whose weights varies with the
        configuration (``Plan.lean``) then evaluates only f and M (no potentials, no monitoring quantities)."""
        if not self.plan.lean:
            return self.forward(q, qd, aux).qdd
        aux = self._inputs(q, qd, aux)
        f, M, *_, qdd, ok = self._root_rmp_maybe_compiled(q, qd, aux, True)
        return self._resolved(q, qd, aux, f, M, qdd, ok)

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


def _row(s: int) -> Callable[[Tensor], Tensor]:
    """Row ``s`` of a group's ``(G, B, ...)`` quantity: member s's."""
    return lambda t: t[s]


def _compile_failure(error: BaseException) -> str:
    """What made torch.compile fail, in one line: the innermost cause (a backend's own exception, which dynamo
    wraps in a message whose first line only names the backend), as ``Type: first line``."""
    while True:
        inner = getattr(error, "inner_exception", None) or error.__cause__
        if inner is None or inner is error:
            break
        error = inner
    text = str(error).strip()
    return f"{type(error).__name__}: {text.splitlines()[0][:200]}" if text else type(error).__name__
