"""The per-level solver: buffers of one pyramid level and the preconditioned primal–dual
iterations on the linearised model (MODEL.md §3–§5).

The solver does not know about pyramids: it is given the sampled (texture) images of one
level and a starting point, and it re-linearises (``linearise``), iterates (``iterate``)
and filters (``median``) on request. :mod:`lfsf.estimate` drives it coarse to fine.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from lfsf import device as _device

#: Levels up to this width use ``median_radius`` as it is; wider ones scale it
#: (:meth:`LevelSolver.median_radius`). At 640×480, radius 2 on every level gave `paper`
#: a flow EPE of 0.0785, 3 on every level 0.0740; at 160×120 and 320×240, 3 was worse
#: than 2 (`large_motion` flow 0.105 → 0.141 at 320×240).
MEDIAN_WIDTH = 320

#: The fill (:meth:`LevelSolver.fill_hidden`) also takes the points of the estimate whose
#: t2 pixel holds a point nearer by more than this (px per view step; the z-buffer test
#: :func:`lfsf.kernels.occlusion.hidden_at_t2` of the finest level's x, not spread). The
#: linearisations' test keeps ``occlusion_margin`` (0.25), which spares the compressing
#: slopes, and so misses the points hidden by a surface close in depth: they keep the
#: flow that hid them. At this margin the farther of two points that a slope steeper than
#: 0.02 px per view step a pixel lands together is taken too; on a smooth surface the
#: fill gives it about its own motion. The points so taken are also left out of the
#: surface fits that follow (as sources and as targets). Thirty-seventh session,
#: geometric means of δ1 / δ2 / EPE against the fill without it: 1.000 / 0.953 / 0.999
#: over 40 scenes at 160×120, 1.000 / 0.975 / 1.000 over `random-32…95`, 1.000 / 0.966 /
#: 0.996 over 13 at 320×240, 1.000 / 0.935 / 0.990 with noise σ = 0.02.
FILL_MARGIN = 0.02


class LevelSolver:
    """Preconditioned primal–dual solver of the linearised scene-flow model on one level.

    Parameters
    ----------
    samples1, samples2 : wp.array3d of float, shape (S, h, w)
        Texture parts of the sub-aperture images L(·, φ_s, t1) and L(·, φ_s, t2); s = 0 is
        the centre view.
    centre1, centre2 : wp.array2d of float, shape (h, w)
        Centre views (intensities) at t1 and t2, for the diffusion tensors Γ_t1, Γ_t2
        (and Γ_uv of the flow, see ``_tensors``).
    phis : wp.array of vec2, shape (S,)
        Angular offsets φ_s (view steps).
    weights : wp.array of vec3, shape (S,)
        (λ1, λ2, λ3) per sample, already divided by the sample count.
    params : lfsf.Params
    device : str
    colour1 : wp.array3d of float, shape (3, h, w), optional
        The t1 centre view in colour (R, G, B planes): Γ_t1 is then Di Zenzo's tensor of
        the three channels (:func:`lfsf.kernels.tgv.colour_diffusion_tensor`) instead of
        the grey ``centre1``'s (``Params.colour_tensor``).

    Call ``set_state`` and then ``linearise`` before ``iterate``: the data term's buffers
    are allocated uninitialised and filled there.

    With one sample (M = 1, the centre view alone) no data row involves δ1 or δ2: the
    solver then iterates on (u, v) alone, as vec2 (``flow_only``), and carries δ1, δ2 (and
    their w) through unchanged, which is what the four-unknown iterations do to them from
    a constant start, at half the memory traffic. The kernels are the same (generic over
    :data:`lfsf.kernels.common.UNKNOWNS`).
    """

    def __init__(self, samples1, samples2, centre1, centre2, phis, weights, params, device: str,
                 level_scale: float = 1.0, colour1=None):
        from lfsf.kernels import data_term, tgv

        wp = _device.warp()
        self.params = params
        self.device = device
        self.level_scale = level_scale  # this level's width / the full width
        self.samples1, self.samples2 = samples1, samples2
        self.phis, self.weights = phis, weights
        n, h, w = samples1.shape
        self.shape = (h, w)
        self.span, self.per_row = _device.row_span(device, w)  # pixels per thread (iteration steps)
        self.bands = 1 if h * w < _device.SMALL_IMAGE else None  # small levels: no thread pool
        self.flow_only = n == 1
        self.vec = wp.vec2 if self.flow_only else wp.vec4
        self._held: dict[str, np.ndarray] = {}  # flow only: the (δ1, δ2) parts of x, w0, w1

        def zeros4():
            return wp.zeros((h, w), dtype=self.vec, device=device)

        # diffusion tensors: Γ_t1 for δ1 (fixed for the level), Γ_t2 for δ2 and Γ_uv for the
        # flow (set at each linearisation, see _tensors)
        self.centre1, self.centre2 = centre1, centre2
        self.tensor1 = wp.empty((h, w), dtype=wp.vec3, device=device)
        if colour1 is not None and tuple(colour1.shape) != (3, h, w):
            raise ValueError(f"colour1 must be (3, {h}, {w}) (R, G, B planes of the level), "
                             f"got {tuple(colour1.shape)}")
        if colour1 is not None and not self.flow_only:
            self._launch(tgv.colour_diffusion_tensor, inputs=[colour1, params.gamma, params.beta],
                         outputs=[self.tensor1])
        else:
            self._launch(tgv.diffusion_tensor, inputs=[centre1, params.gamma, params.beta], outputs=[self.tensor1])
        if self.flow_only:
            # Γ_uv of a zero δ̂1 is Γ_t1, and no δ is iterated: one tensor for all three
            self.tensor2 = self.tensor3 = self.tensor1
        else:
            self.tensor2 = wp.empty((h, w), dtype=wp.vec3, device=device)
            self.tensor3 = wp.empty((h, w), dtype=wp.vec3, device=device)
        self.warped2 = wp.empty((h, w), dtype=float, device=device)
        # Γ's entries (Γ00, Γ01, Γ11) per unknown, as the TGV steps read them (_expand_tensors)
        self.tensor_entries = tuple(wp.empty((h, w), dtype=self.vec, device=device) for _ in range(3))

        # data term: coefficients per pixel and sample, the row flags, the scaled duals q̃
        # (all in lane storage, lfsf.kernels.data_term; ``*_store`` as floats or words, the
        # others the same memory as vectors of ``lanes``), and Kᵀq
        self.lanes = data_term.data_lanes(device)
        self.coef_store, self.coef = lane_storage(h, w, n, data_term.COEFFICIENTS, self.lanes, device)
        self.flags_store, self.flags = lane_storage(h, w, 1, data_term.pixel_flag_words(n), self.lanes, device,
                                                    flags=True)
        self.grad_j2_store, self.grad_j2 = lane_storage(h, w, 1, 2, self.lanes, device)  # ∇J2 (A8, A9 from it)
        self.q_store, self.q = lane_storage(h, w, n, data_term.DUALS, self.lanes, device)  # zeroed by set_state
        self.data_colsum = zeros4()
        self.data_grad = zeros4()
        # primal: x = (δ1, δ2, u, v) (flow only: (u, v)), w = (w0, w1), their over-relaxed copies, x̂
        self.x, self.x_bar, self.x_hat = zeros4(), zeros4(), zeros4()
        self.w0, self.w1, self.w0_bar, self.w1_bar = zeros4(), zeros4(), zeros4(), zeros4()
        # TGV duals
        self.y0, self.y1 = zeros4(), zeros4()
        self.z00, self.z01, self.z10, self.z11 = zeros4(), zeros4(), zeros4(), zeros4()
        # preconditioners
        self.tau_x, self.tau_w0, self.tau_w1 = zeros4(), zeros4(), zeros4()
        self.sigma_y = zeros4()  # one step for both components of y (tgv_preconditioner)
        self.scratch = zeros4()
        # the median's sorted window columns of u and v and their δ1 extents (median), made on its first use
        self._median_columns: tuple | None = None
        # geometric occlusion at t2: z-buffer of δ2 and the hidden mask
        self.zbuf = wp.zeros((h, w), dtype=float, device=device)
        # geometric visibility of the side views: a z-buffer per sample, t1 and t2
        views = n if params.visibility and not self.flow_only else 1
        self.view_zbuf1 = wp.zeros((views, h, w) if views > 1 else (1, 1, 1), dtype=float, device=device)
        self.view_zbuf2 = wp.zeros((views, h, w) if views > 1 else (1, 1, 1), dtype=float, device=device)
        self.hidden2 = wp.zeros((h, w), dtype=float, device=device)
        self.scratch1 = wp.zeros((h, w), dtype=float, device=device)
        self._iteration = None  # the recorded iteration (``iterate``)
        self._tensors()  # (expands Γ's entries, except flow only:)
        if self.flow_only:
            self._expand_tensors()  # Γ_t1 for all three, set once

    def _launch(self, kernel, inputs, outputs):
        _device.launch_rows(kernel, dim=self.shape, inputs=inputs, outputs=outputs, device=self.device,
                            bands=self.bands)

    def _launch_spans(self, kernel, inputs, outputs):
        """A kernel whose threads each walk ``self.span`` pixels of a row."""
        _device.launch_rows(kernel, dim=(self.shape[0], self.per_row), inputs=inputs, outputs=outputs,
                            device=self.device, bands=self.bands)

    # --- state ---------------------------------------------------------------------------

    def set_state(self, x, w0: np.ndarray | None = None, w1: np.ndarray | None = None) -> None:
        """Start from x (h, w, 4) = (δ1, δ2, u, v) and w (each (h, w, 4), default 0);
        duals are reset, and the tensors Γ_t2, Γ_uv set from x. Flow only, the (δ1, δ2)
        parts are held as they are. x may also be a vec4 (h, w) device array (the
        estimator's, which stays on the device between levels)."""
        wp = _device.warp()
        h, w = self.shape
        on_device = isinstance(x, wp.array)
        if on_device:
            if tuple(x.shape) != (h, w) or x.dtype != wp.vec4:
                raise ValueError(f"x must be a vec4 array of shape {(h, w)}, got {x.dtype.__name__} {tuple(x.shape)}")
            if self.flow_only:
                x, on_device = x.numpy(), False  # (the held (δ1, δ2) parts stay on the host)
        for name, value in (("x", x), ("w0", w0), ("w1", w1)):
            if name == "x" and on_device:
                wp.copy(self.x, value)
                wp.copy(self.x_bar, value)
                continue
            if value is None and name != "x":  # (zeroed where they are: nothing to upload)
                if self.flow_only:
                    self._held[name] = np.zeros((h, w, 2), np.float32)
                getattr(self, name).zero_()
                getattr(self, name + "_bar").zero_()
                continue
            arr = np.zeros((h, w, 4), np.float32) if value is None else np.ascontiguousarray(value, np.float32)
            if arr.shape != (h, w, 4):
                raise ValueError(f"{name} must have shape {(h, w, 4)}, got {arr.shape}")
            if self.flow_only:
                self._held[name] = arr[..., :2].copy()
                arr = np.ascontiguousarray(arr[..., 2:])
            src = wp.array(arr, dtype=self.vec, device=self.device)
            wp.copy(getattr(self, name), src)
            wp.copy(getattr(self, name + "_bar"), src)
        for dual in (self.q_store, self.y0, self.y1, self.z00, self.z01, self.z10, self.z11):
            dual.zero_()
        wp.copy(self.x_hat, self.x)
        self._tensors()

    def tgv_duals(self) -> list[np.ndarray]:
        """The TGV duals (y0, y1, z00, z01, z10, z11) as numpy arrays of shape (h, w, 4),
        the unknowns' components (δ1, δ2, u, v) last (flow only: (h, w, 2), (u, v))."""
        return [getattr(self, name).numpy() for name in TGV_DUALS]

    def take_coarse(self, coarse: LevelSolver, duals: bool) -> None:
        """After :meth:`set_state`: w0 and w1 from the coarser level's solver ``coarse``,
        upsampled bilinearly on the device (as the unknowns between levels, unscaled),
        and with ``duals`` (``params.carry_duals``) the (δ1, δ2) parts of its TGV duals,
        their flow parts left at the 0 that :meth:`set_state` gave them. Flow only,
        no duals are carried, and w's held (δ1, δ2) parts stay 0, which is what
        upsampling the coarser level's zeros gives."""
        from lfsf.kernels import pyramid

        wp = _device.warp()
        if coarse.flow_only != self.flow_only:
            raise ValueError("take_coarse: the coarser level's solver has other unknowns (flow only or not)")
        ones = wp.vec4(1.0, 1.0, 1.0, 1.0)
        for name in ("w0", "w1"):
            self._launch(pyramid.upsample_unknowns, inputs=[getattr(coarse, name), ones, 4],
                         outputs=[getattr(self, name)])
            wp.copy(getattr(self, name + "_bar"), getattr(self, name))
        if duals and not self.flow_only:
            for name in TGV_DUALS:
                self._launch(pyramid.upsample_unknowns, inputs=[getattr(coarse, name), ones, 2],
                             outputs=[getattr(self, name)])

    def unknowns(self) -> np.ndarray:
        """x = (δ1, δ2, u, v) as a numpy array of shape (h, w, 4)."""
        return self._full("x", self.x)

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, w0, w1) as numpy arrays of shape (h, w, 4)."""
        return self._full("x", self.x), self._full("w0", self.w0), self._full("w1", self.w1)

    def linearisation_point(self) -> np.ndarray:
        """x̂ as a numpy array of shape (h, w, 4)."""
        return self._full("x", self.x_hat)

    def _full(self, name: str, array) -> np.ndarray:
        """A buffer of unknowns as (h, w, 4); flow only, with the held (δ1, δ2) of ``name``."""
        a = array.numpy()
        return np.concatenate([self._held[name], a], -1) if self.flow_only else a

    # --- one warp ------------------------------------------------------------------------

    def linearise(self) -> None:
        """Linearise the data term at the current x (x̂ ← x): coefficients A1…A9 of every
        sample, then the diagonal preconditioners τ, σ."""
        from lfsf.kernels import data_groups, tgv

        wp = _device.warp()
        p = self.params
        wp.copy(self.x_hat, self.x)
        wp.copy(self.x_bar, self.x)
        wp.copy(self.w0_bar, self.w0)
        wp.copy(self.w1_bar, self.w1)
        self.find_hidden()
        use_zbuf = self.find_visible()
        self._flow_tensor()
        kernel, columns = data_groups.coefficients_kernel(self.shape[1], self.lanes)
        _device.launch_rows(kernel, dim=(self.shape[0], columns),
                            inputs=[self.samples1, self.samples2, self.phis, self.weights, self.x_hat,
                                    p.occlusion_ratio, self.hidden2, self.view_zbuf1, self.view_zbuf2,
                                    self.view_margin(), use_zbuf, self.lanes, int(p.cubic)],
                            outputs=[self.coef_store, self.flags_store, self.grad_j2_store, self.data_colsum,
                                     self.q_store],
                            device=self.device, bands=self.bands)
        self._launch(tgv.tgv_preconditioner,
                     inputs=[self.data_colsum, self.tensor1, self.tensor2, self.tensor3, self.alpha0(), p.alpha1, p.eps,
                             p.step_ratio],
                     outputs=[self.tau_x, self.tau_w0, self.tau_w1, self.sigma_y])

    def _tensors(self) -> None:
        """Γ_t2 and Γ_uv at x̂, at the start of the level (``set_state``). Γ_t2 is the
        tensor of the t2 centre view, which δ2 (a map on the t1 grid) sees at p + û:
        warped there when ``params.warp_tensor2`` (else the view as it is). It stays
        fixed over the level's warps (re-warping it at every warp measured worse for δ2:
        slanted δ2 MSE 0.022 against 0.037 at 320×240)."""
        from lfsf.kernels import sampling, tgv

        p = self.params
        if self.flow_only:
            return
        image2 = self.centre2
        if p.warp_tensor2:
            self._launch(sampling.warp_by_flow, inputs=[self.centre2, self.x_hat], outputs=[self.warped2])
            image2 = self.warped2
        self._launch(tgv.diffusion_tensor, inputs=[image2, p.gamma, p.beta], outputs=[self.tensor2])
        self._flow_tensor()

    def _flow_tensor(self) -> None:
        """Γ_uv at x̂ (at every linearisation): the tensor of the t1 centre view with δ̂1
        as a second channel of weight ``params.flow_edge_weight`` (0: Γ_t1). Objects at
        different depths move differently, so depth edges are where the flow may jump."""
        from lfsf.kernels import tgv

        p = self.params
        if self.flow_only:
            return
        self._launch(tgv.joint_diffusion_tensor, inputs=[self.centre1, self.x_hat, p.flow_edge_weight, p.gamma,
                                                         p.beta], outputs=[self.tensor3])
        self._expand_tensors()

    def _expand_tensors(self) -> None:
        """Γ's entries per unknown (``self.tensor_entries``) from the three tensors, after they change
        (:data:`lfsf.kernels.tgv.expand_tensor`): the TGV steps read them as the unknowns'
        vectors, contiguous like the unknowns."""
        from lfsf.kernels import tgv

        self._launch(tgv.expand_tensor, inputs=[self.tensor1, self.tensor2, self.tensor3],
                     outputs=list(self.tensor_entries))

    def find_visible(self) -> int:
        """The view z-buffers of x̂ (``params.visibility``): of δ̂1 at p (t1) and of δ̂2
        at p + û (t2) in every sampled view. Returns 1 where they are made, else 0 (the
        data term then keeps the best half)."""
        from lfsf.kernels import occlusion

        if self.view_zbuf1.shape[0] == 1:
            return 0
        n, h, w = self.view_zbuf1.shape
        for zbuf, component in ((self.view_zbuf1, 0), (self.view_zbuf2, 1)):
            zbuf.fill_(occlusion.EMPTY)
            _device.launch_rows(occlusion.splat_views, dim=(n, h, self.per_row),
                                inputs=[self.x_hat, component, component, self.phis, self.span], outputs=[zbuf],
                                device=self.device)  # bands of whole samples: the atomics never meet
        return 1

    def view_margin(self) -> float:
        """How much nearer (px per view step, in this level's pixels) a point of the view
        z-buffers must be to hide a sample: ``params.occlusion_margin``, a full-resolution
        figure, times the level's scale, as the disparities themselves scale. Unscaled, a
        coarse level let a jump of 0.25·2^k full-resolution px pass unseen; scaled, HCI
        antinous MSE×100 went 3.26 → 2.99 and the Lytro scene 0.0132 → 0.0129 px, with
        the synthetic scenes within their spread (docs/accuracy.md)."""
        return self.params.occlusion_margin * self.level_scale

    def _zbuffer_test(self, x, margin: float, outside: float, out) -> None:
        """:func:`lfsf.kernels.occlusion.hidden_at_t2` of the unknowns ``x`` (a vec4 (h, w)
        device array) into ``out``: δ1 splatted where the points land at t2 (into
        ``zbuf``), each point tested against its pixel's nearest with ``margin``,
        ``outside`` where it lands outside the image. The linearisations' test, the
        fill's and the reported mask all start from it."""
        from lfsf.kernels import occlusion

        self.zbuf.fill_(occlusion.EMPTY)
        _device.launch_rows(occlusion.splat_depth, dim=self.shape, inputs=[x], outputs=[self.zbuf],
                            device=self.device, bands=1)  # atomics: one launch
        self._launch(occlusion.hidden_at_t2, inputs=[x, self.zbuf, margin, outside], outputs=[out])

    def find_hidden(self) -> None:
        """Mark the points of x̂ hidden at t2 by a nearer point (``hidden2``; all zero when
        ``params.occlusion_margin`` is 0). Its margin stays in level pixels: scaled like
        :meth:`view_margin`, it marked the compressing slopes of coarse levels hidden and
        dropped their t2 rows (320×240 `paper` flow EPE 0.061 → 0.068, δ2 0.033 → 0.051)."""
        from lfsf.kernels import occlusion

        margin = self.params.occlusion_margin
        if margin <= 0 or self.flow_only:  # flow only: no t2 view but the centre
            self.hidden2.zero_()
            return
        self._zbuffer_test(self.x_hat, margin, 0.0, self.scratch1)
        self._launch(occlusion.spread_hidden, inputs=[self.x_hat, self.scratch1, margin, int(self.params.occlusion_reach)],
                     outputs=[self.hidden2])

    def hidden_at_t2(self, x: np.ndarray) -> np.ndarray:
        """Where the points of an estimate x (h, w, 4) are hidden at t2 by a nearer
        point (:meth:`find_hidden`'s test at x̂ = x), as a bool (h, w) array. Leaves the
        solver's state as it was but for x̂ and ``hidden2``, which :meth:`linearise`
        sets afresh."""
        wp = _device.warp()
        if self.flow_only:
            return np.zeros(self.shape, bool)
        return self.find_hidden_at(wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec4,
                                            device=self.device)).numpy() > 0.5

    def occluded_at(self, x: np.ndarray) -> np.ndarray:
        """Where the points of an estimate x (h, w, 4) are not seen in the centre view at
        t2, as a bool (h, w) array: hidden by a nearer point (:meth:`find_hidden`'s
        z-buffer test with ``params.occlusion_margin``, its default where the setting is
        0, without the test's spread over the surface, which the estimator wants cautious
        and a result wants exact) or carried out of the image by their flow (their nearest
        t2 pixel outside it), as the synthetic ground truth's ``occluded`` counts them.
        Leaves the solver's state as it was but for x̂ and ``hidden2``, which
        :meth:`linearise` sets afresh. Not defined for flow only (no depth): ValueError."""
        if self.flow_only:
            raise ValueError("occluded_at needs the disparities: flow only estimates none")
        margin = self.params.occlusion_margin
        if margin <= 0:  # the estimator's tests are off; the mask keeps the default's
            margin = next(f.default for f in dataclasses.fields(self.params) if f.name == "occlusion_margin")
        self.x_hat.assign(np.ascontiguousarray(x, np.float32))
        self._zbuffer_test(self.x_hat, margin, 1.0, self.hidden2)
        return self.hidden2.numpy() > 0.5

    def find_hidden_at(self, x):
        """:meth:`hidden_at_t2` on the device: x, the unknowns (δ1, δ2, u, v) as a vec4
        (h, w) device array; returns ``hidden2`` (float, 1 where hidden), which holds until
        the next :meth:`linearise`. Flow only, 0 everywhere."""
        wp = _device.warp()
        if tuple(x.shape) != self.shape:
            raise ValueError(f"x must be {self.shape}, got {tuple(x.shape)}")
        if not self.flow_only:
            wp.copy(self.x_hat, x)
        self.find_hidden()
        return self.hidden2

    def fill_hidden(self, flagged=None, hidden=None) -> None:
        """Where a point is hidden at t2 (``hidden2`` of the last linearisation), give it
        the motion of the points of its own surface around it that are seen at t2: δ2 =
        δ1 plus their depth change, (u, v) their flow
        (:func:`lfsf.kernels.occlusion.fill_hidden_motion`; ``params.hidden_fill_sigma``,
        0: off, and ``params.hidden_fill_depth``). No view constrains the point at t2,
        and the regulariser alone reaches over to the occluder. ``flagged`` (bool (h, w),
        optional; or a float device array, 1 where flagged): points another test
        suspects hidden (the estimator's searches), or whose flow finds no match at t2
        (:func:`lfsf.estimate._unmatched`); their δ2 is set the same way, their flow is
        kept, and they are no source of the depth change. ``hidden`` (the same types,
        optional): points to treat as hidden at t2 as well (the estimator's points whose
        flow is lost), which join ``hidden2``. First the
        points of x whose t2 pixel holds a point nearer by more than ``FILL_MARGIN`` join
        ``hidden2``, which holds until the next :meth:`linearise`. The estimator calls it
        once, after the finest level's last warp."""
        from lfsf.kernels import fusion, occlusion

        sigma = self.params.hidden_fill_sigma
        if sigma <= 0 or self.flow_only or self.params.occlusion_margin <= 0:
            return
        for name, mask in (("flagged", flagged), ("hidden", hidden)):
            if mask is not None and tuple(mask.shape) != self.shape:
                raise ValueError(f"{name} must be {self.shape}, got {tuple(mask.shape)}")
        wp = _device.warp()
        radius = int(math.ceil(3.0 * sigma))
        depth_sigma = self.params.hidden_fill_depth * self.level_scale

        def load(mask) -> None:  # into scratch1, as floats
            if isinstance(mask, np.ndarray):
                self.scratch1.assign(np.ascontiguousarray(mask, np.float32))
            else:
                wp.copy(self.scratch1, mask)

        # the z-buffer test of x at FILL_MARGIN, joined to hidden2; then ``hidden``
        self._zbuffer_test(self.x, FILL_MARGIN, 0.0, self.scratch1)
        self._launch(fusion.either_above, inputs=[self.hidden2, 0.5, self.scratch1, 0.5], outputs=[self.hidden2])
        if hidden is not None:
            load(hidden)
            self._launch(fusion.either_above, inputs=[self.hidden2, 0.5, self.scratch1, 0.5], outputs=[self.hidden2])
        if flagged is None:
            self.scratch1.zero_()
        else:
            load(flagged)
        self._launch(occlusion.fill_hidden_motion, inputs=[self.hidden2, self.scratch1, sigma, depth_sigma, radius],
                     outputs=[self.x, self.x_bar])

    def iterate(self, n: int) -> None:
        """n preconditioned primal–dual iterations (Chambolle & Pock 2011). The three
        launches of an iteration are recorded on first use and replayed (as a captured
        graph on CUDA, :class:`lfsf.device.CapturedLoop`)."""
        if self._iteration is None:
            self._iteration = _device.CapturedLoop(self._iteration_steps(), device=self.device)
        self._iteration.run(n)

    def _iteration_steps(self) -> list:
        from lfsf.kernels import tgv

        p = self.params
        sigma_z = 1.0 / (2.0 * p.alpha0 * p.step_ratio)
        dim = (self.shape[0], self.per_row)

        def record(kernel, inputs, outputs, dim=dim):
            return _device.RecordedRows(kernel, dim, inputs=inputs, outputs=outputs, device=self.device,
                                        bands=self.bands)

        data_step, columns, (coef, flags, grad_j2, q), last = dual_data_launch(
            self.lanes, self.device, self.shape[1], (self.coef_store, self.coef), (self.flags_store, self.flags),
            (self.grad_j2_store, self.grad_j2), (self.q_store, self.q))
        dual_step, primal_step = tgv.tgv_kernels(self.device)
        return [
            record(data_step,
                   inputs=[coef, flags, self.weights, grad_j2, self.x_bar, self.x_hat, p.eps, p.step_ratio, last],
                   outputs=[q, self.data_grad], dim=(self.shape[0], columns)),
            record(dual_step,
                   inputs=[self.x_bar, self.w0_bar, self.w1_bar, *self.tensor_entries, self.sigma_y, sigma_z,
                           p.alpha0, p.alpha1, self.span],
                   outputs=[self.y0, self.y1, self.z00, self.z01, self.z10, self.z11]),
            record(primal_step,
                   inputs=[self.data_grad, self.y0, self.y1, self.z00, self.z01, self.z10, self.z11,
                           *self.tensor_entries, self.tau_x, self.tau_w0, self.tau_w1, self.alpha0(), p.alpha1,
                           self.span],
                   outputs=[self.x, self.w0, self.w1, self.x_bar, self.w0_bar, self.w1_bar]),
        ]

    def alpha0(self):
        """α0 of each unknown, as the unknowns' vector: ``params.alpha0`` for δ1 and δ2,
        ``params.flow_alpha0`` for u and v."""
        p = self.params
        if self.flow_only:
            return self.vec(p.flow_alpha0, p.flow_alpha0)
        return self.vec(p.alpha0, p.alpha0, p.flow_alpha0, p.flow_alpha0)

    def median_radius(self) -> int:
        """The median filter's radius on this level (:func:`level_median_radius`)."""
        return level_median_radius(self.params.median_radius, self.shape[1])

    def median(self) -> None:
        """Median-filter the flow (u, v) of x over the pixels of a (2r+1)² window (r =
        :meth:`median_radius`) whose δ1 is within ``params.median_tolerance`` (scaled to the
        level) of the centre pixel's (:func:`flow_median`)."""
        wp = _device.warp()
        radius = self.median_radius()
        if radius <= 0:
            return
        tolerance = self.params.median_tolerance * self.level_scale
        self._median_columns = flow_median(self.x, radius, tolerance, self.scratch, self.device, self.bands,
                                           self._median_columns)
        wp.copy(self.x, self.scratch)
        wp.copy(self.x_bar, self.scratch)

    # --- diagnostics ---------------------------------------------------------------------

    def data_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The linearised data rows as NumPy arrays, sample-major: A1…A9 as (9, S, h, w)
        and the row weights w1…w3 as (3, S, h, w) (λ_k of the sample where the row is in,
        else 0). For tests and diagnostics, not the hot path."""
        from lfsf.kernels import data_term

        w = self.shape[1]
        c = unpack_coefficients(from_lanes(self.coef_store.numpy(), w, self.lanes, data_term.COEFFICIENTS),
                                from_lanes(self.grad_j2_store.numpy(), w, self.lanes, 2)[:, :, 0])
        a = np.moveaxis(c.astype(np.float64), (3, 2), (0, 1))  # (9, S, h, w)
        lam = self.weights.numpy().astype(np.float64)  # (S, 3)
        words = from_lanes(self.flags_store.numpy(), w, self.lanes, self.flags_store.shape[2] // self.lanes)
        on = unpack_flags(words[:, :, 0], lam.shape[0])  # (h, w, S, 3)
        on = np.moveaxis(on, (3, 2), (0, 1))
        return a, np.where(on, lam.T[:, :, None, None], 0.0)

    def energy(self) -> float:
        """Energy of the linearised model at the current (x, w): Σ_s Σ_k w_k|ρ_k| +
        α1 Σ|Γ(∇x − w)| + α0 Σ|∇w| (α0 of each unknown: :meth:`alpha0`; NumPy; for tests
        and diagnostics, not the hot path)."""
        p = self.params
        x, w0, w1 = self.state()
        d = x - self.linearisation_point()
        a, (wt1, wt2, wt3) = self.data_rows()
        rho1 = a[1] - a[0] * d[..., 0]
        rho2 = a[3] - a[2] * d[..., 1] + a[7] * d[..., 2] + a[8] * d[..., 3]
        rho3 = a[6] + a[0] * d[..., 0] - a[2] * d[..., 1] - a[4] * d[..., 2] - a[5] * d[..., 3]
        data = float(np.sum(wt1 * np.abs(rho1) + wt2 * np.abs(rho2) + wt3 * np.abs(rho3)))
        g1, g2, g3 = self.tensor1.numpy(), self.tensor2.numpy(), self.tensor3.numpy()
        tens = [np.stack([g1[..., k], g2[..., k], g3[..., k], g3[..., k]], -1) for k in range(3)]
        gx, gy = forward_gradient(x)
        r0, r1 = gx - w0, gy - w1
        t0 = tens[0] * r0 + tens[1] * r1
        t1 = tens[1] * r0 + tens[2] * r1
        first = float(np.sum(np.sqrt(t0**2 + t1**2)))
        dx0, dy0 = forward_gradient(w0)
        dx1, dy1 = forward_gradient(w1)
        alpha0 = np.array([p.alpha0, p.alpha0, p.flow_alpha0, p.flow_alpha0])  # (δ1, δ2, u, v)
        second = float(np.sum(alpha0 * np.sqrt(dx0**2 + dy0**2 + dx1**2 + dy1**2)))
        return data + p.alpha1 * first + second


#: The TGV duals' buffers: y for ∇x − w (two components), z for ∇w (four).
TGV_DUALS = ("y0", "y1", "z00", "z01", "z10", "z11")


def lane_storage(h: int, w: int, n: int, values: int, lanes: int, device: str, flags: bool = False):
    """Lane storage (:mod:`lfsf.kernels.data_term`) of ``values`` floats (``flags``:
    int32 words) per sample for n samples of an (h, w) level: the array (h, ⌈w / L⌉,
    n · values · L) and the same memory as vectors of L (h, ⌈w / L⌉, n · values). Keep
    the first alive while the second is used: the second holds a reference to the first
    (:func:`lfsf.device.vector_view`). Uninitialised where every lane holds a pixel (``data_coefficients``
    writes every pixel's coefficients, ``set_state`` zeroes the duals); zeroed where
    lanes run past the row's end, which no kernel writes (zeroing 300 MB at 640×480
    took 1.3 s of the solvers' set-up)."""
    from lfsf.kernels.common import lane_vector
    from lfsf.kernels.data_term import flag_vector

    wp = _device.warp()
    groups = -(-int(w) // lanes)
    alloc = wp.empty if groups * lanes == w else wp.zeros
    store = alloc((h, groups, n * values * lanes), dtype=wp.int32 if flags else float, device=device)
    vector = flag_vector(lanes) if flags else lane_vector(lanes)
    return store, _device.vector_view(store, vector, (h, groups, n * values))


def dual_data_launch(lanes: int, device: str, width: int, coef, flags, grad_j2, q):
    """How the data term's dual step is launched on lane storage of ``lanes`` pixels a
    group (:func:`lane_storage`; ``coef``, ``flags``, ``grad_j2``, ``q``: its (store,
    vector view) pairs): (kernel, columns to launch over with the rows, the four arrays
    as the kernel reads them, its last input). A pixel per thread
    (:func:`lfsf.kernels.data_term.pixelwise`) reads the stores and takes ``lanes``; the
    groups' kernel reads the vectors and takes the groups each thread walks."""
    from lfsf.kernels import data_term

    kernel = data_term.dual_data_kernel(lanes)
    if data_term.pixelwise(lanes):
        return kernel, int(width), tuple(a[0] for a in (coef, flags, grad_j2, q)), int(lanes)
    groups, per_row = _device.row_span(device, coef[1].shape[1])
    return kernel, per_row, tuple(a[1] for a in (coef, flags, grad_j2, q)), groups


def from_lanes(a: np.ndarray, w: int, lanes: int, values: int) -> np.ndarray:
    """Lane storage (h, groups, n · values · L) as (h, w, n, values)."""
    h, groups, size = a.shape
    n = size // (values * lanes)
    return np.ascontiguousarray(
        a.reshape(h, groups, n, values, lanes).transpose(0, 1, 4, 2, 3).reshape(h, groups * lanes, n, values)[:, :w])


def unpack_coefficients(stored: np.ndarray, grad_j2: np.ndarray) -> np.ndarray:
    """A1 … A9 (…, S, 9) from the seven stored (…, S, 7) and ∇J2 (…, 2) of each pixel,
    A8, A9 = ∇J2 − (A5, A6) in float32 as the kernels rebuild them."""
    stored = np.asarray(stored, np.float32)
    g = np.asarray(grad_j2, np.float32)[..., None, :]
    return np.concatenate([stored, (g[..., 0] - stored[..., 4])[..., None], (g[..., 1] - stored[..., 5])[..., None]],
                          axis=-1)


def pack_coefficients(coef: np.ndarray, grad_j2: np.ndarray) -> np.ndarray:
    """The seven stored values (…, S, 7) of A1 … A9 (…, S, 9) whose A8, A9 are ∇J2 −
    (A5, A6) (checked, in float32)."""
    coef = np.asarray(coef, np.float32)
    stored = np.ascontiguousarray(coef[..., :7])
    if not np.array_equal(unpack_coefficients(stored, grad_j2), coef):
        raise ValueError("A8, A9 are not ∇J2 − (A5, A6)")
    return stored


def pack_flags(on: np.ndarray) -> np.ndarray:
    """Row flags (…, S, 3) of booleans (row k of sample s in) as the kernels' int32 words
    (…, 3 W), W = :func:`lfsf.kernels.data_term.flag_words` of S: bit s % 31 of word
    k W + s // 31."""
    from lfsf.kernels.data_term import FLAG_BITS, flag_words, pixel_flag_words

    on = np.asarray(on, bool)
    n = on.shape[-2]
    words = flag_words(n)
    out = np.zeros(on.shape[:-2] + (pixel_flag_words(n),), np.int32)
    for s in range(n):
        for k in range(3):
            out[..., k * words + s // FLAG_BITS] |= on[..., s, k].astype(np.int32) << (s % FLAG_BITS)
    return out


def unpack_flags(words: np.ndarray, n: int) -> np.ndarray:
    """The booleans (…, n, 3) of row-flag words (…, 3 W) (:func:`pack_flags`)."""
    from lfsf.kernels.data_term import FLAG_BITS

    words = np.asarray(words, np.int32)
    w = words.shape[-1] // 3
    out = np.zeros(words.shape[:-1] + (n, 3), bool)
    for s in range(n):
        for k in range(3):
            out[..., s, k] = (words[..., k * w + s // FLAG_BITS] >> (s % FLAG_BITS)) & 1 != 0
    return out


def to_lanes(a: np.ndarray, lanes: int) -> np.ndarray:
    """(h, w, n, values) as lane storage (h, ⌈w / L⌉, n · values · L), float32 (int32 for
    row-flag words), zero past the row's end."""
    h, w, n, values = a.shape
    groups = -(-w // lanes)
    padded = np.zeros((h, groups * lanes, n, values), np.int32 if a.dtype == np.int32 else np.float32)
    padded[:, :w] = a
    return np.ascontiguousarray(padded.reshape(h, groups, lanes, n, values).transpose(0, 1, 3, 4, 2)
                                .reshape(h, groups, n * values * lanes))


def flow_median(x, radius: int, tolerance: float, out, device: str, bands=None, columns=None):
    """out = x with its flow median-filtered over the (2r+1)² windows' pixels on the centre
    pixel's surface (δ1 within ``tolerance``; :func:`lfsf.kernels.median.median_flow`'s
    values): for r ≤ LOCAL_RADIUS from sorted window columns, a thread for two pixels
    (:func:`lfsf.kernels.median.flow_median_pairs`), into ``columns`` (the buffers of an
    earlier call of the same radius and shape, or None to make them). Returns the buffers,
    for the next call."""
    from lfsf.kernels import median

    wp = _device.warp()
    h, w = x.shape
    if radius > median.LOCAL_RADIUS:
        _device.launch_rows(median.median_flow, dim=(h, w), inputs=[x, radius, tolerance], outputs=[out],
                            device=device, bands=bands)
        return columns
    side = 2 * radius + 1
    if columns is None or tuple(columns[0].shape) != (h, w, side):
        columns = (wp.empty((h, w, side), dtype=float, device=device),
                   wp.empty((h, w, side), dtype=float, device=device),
                   wp.empty((h, w), dtype=wp.vec2, device=device))
    _device.launch_rows(median.sorted_flow_columns, dim=(h, w), inputs=[x, radius], outputs=list(columns),
                        device=device, bands=bands)
    _device.launch_rows(median.flow_median_pairs, dim=(h, (w + 1) // 2), inputs=[x, radius, tolerance, *columns],
                        outputs=[out], device=device, bands=bands)
    return columns


def level_median_radius(radius: int, width: int) -> int:
    """The median filter's radius on a level ``width`` pixels wide: ``radius`` up to
    MEDIAN_WIDTH, in proportion to the width on wider levels (at most 3), so that the
    window keeps its share of the image; 0 stays 0 (off)."""
    if radius <= 0:
        return 0
    return min(3, max(radius, int(round(radius * width / MEDIAN_WIDTH))))


def forward_gradient(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward differences along x (axis 1) and y (axis 0), zero at the last column/row."""
    gx = np.zeros_like(a)
    gy = np.zeros_like(a)
    gx[:, :-1] = a[:, 1:] - a[:, :-1]
    gy[:-1, :] = a[1:, :] - a[:-1, :]
    return gx, gy
