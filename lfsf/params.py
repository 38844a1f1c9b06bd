"""Parameters of the light-field scene-flow model, named by the paper's symbols."""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from lfsf._errors import shown_number, whole


@dataclass(frozen=True)
class Params:
    """Every setting of the estimator (Heber & Pock, GCPR 2014; MODEL.md).

    Types are checked, not guessed: a whole-number setting takes an int or a float with
    no fraction (``warps = 3.0`` → 3), a real-valued one any finite int or float, a switch
    exactly true or false (no strings, no 0/1), ``samples`` a list or tuple of whole
    numbers; a bool is no number. Anything else raises ``ValueError`` naming the setting.

    Sampling of the light field (MODEL.md §2)
        circles : M, the number of sampling circles (radii r_i = R·i/(M−1)); M = 1 uses
            the centre view alone (optical flow only).
        samples : N_i, positions on each circle; N_0 must be 1 (the centre view).
        radius : R, the largest sampling radius in view steps; limited to the view grid;
            at least 0.5 with side samples (:data:`MIN_RADIUS`).
        whole_circles : the inner circles moved to the nearest whole view step where
            R·i/(M−1) is not one (an addition; :func:`_on_whole_views`): 1.5 → 2 at R = 3
            (a 7×7 grid). A sample between two views blends them, two copies of the
            scene δ px apart, which biases large disparities: HCI antinous at R = 3
            BadPix(0.07) 27.6 % → 13.2 %, MSE×100 1.99 → 1.72. Off by default: on the
            synthetic scenes of smaller disparities (7×7, 160×120: `paper`, `slanted`,
            `large_motion`, `weak_texture`, random-0…3) the blend does no harm, and whole
            steps cost δ1 / δ2 / EPE 1.27 / 1.24 / 1.12× (geometric means).
    Data term (§3)
        lambda1, lambda2, lambda3 : λ1 (stereo at t1), λ2 (stereo at t2), λ3 (flow).
            Each is divided by the number of samples, so the weights mean the same
            whatever the sampling.
        lambda3_side : the weight of the side samples' ρ3 rows (φ ≠ 0, the cross-time
            rows that tie δ1 to δ2 and the flow) as a fraction of λ3; the centre view's
            ρ3 row (φ = 0, the optical-flow term) keeps λ3. 1 is the paper's model.
        occlusion_ratio : occlusion handling (an addition to the paper): where the samples
            on one side of a line through the centre match better than this fraction of
            the mean, the other side is left out of that pixel's stereo rows (0: off).
        visibility : geometric visibility of the side views (an addition to the paper,
            :mod:`lfsf.kernels.occlusion`): view z-buffers of the current disparities say
            which samples a point nearer by more than ``occlusion_margin`` covers (px per
            view step at full resolution, scaled with the level in the data rows); those
            are left out of the data rows, of the plane sweep's second pass and of the
            fusion of searched values. False: the best-half test alone decides. Where the
            background has little texture, the best half favours the foreground's
            disparity there (HCI antinous MSE×100 19.8 with it alone). Not used where
            the side samples all lie on one side of the centre (two-view stereo,
            ``samples=(1, 1)``): a point hidden from them all keeps no data, and wrong
            near values grow from there (:func:`lfsf.estimate.one_sided`); nor where R is
            below :data:`lfsf.estimate.VISIBILITY_MIN_RADIUS` (2: grids of fewer than 5×5
            views), where they left out more good rows than hidden ones.
        occlusion_margin, occlusion_reach : geometric occlusion at t2 (an addition to
            the paper, :mod:`lfsf.kernels.occlusion`): a point counts as hidden in the t2
            centre view where a point nearer by more than ``occlusion_margin`` px per
            view step (larger δ1) lands on the pixel where it lands; the hidden band then
            spreads ``occlusion_reach`` pixels over its own surface. Every row involving
            t2 is left out there (margin 0: off).
        hidden_fill_sigma : where a point is hidden at t2, no view constrains its δ2 and
            flow, and the regulariser alone reaches over to the occluder's. After the
            finest level's last warp the point takes the motion of the points of its own
            surface around it that are seen at t2: δ2 = δ1 plus their depth change
            δ2 − δ1, (u, v) their flow, averaged with Gaussian weights of this σ (px, out
            to 3σ) times the depth weight of ``hidden_fill_depth``; where none is seen
            there, δ2 = δ1 and the flow stays. The fill also takes the points whose t2
            pixel holds a point nearer by more than ``lfsf.solver.FILL_MARGIN`` (0.02),
            hidden by a surface close in depth. 0: off (an addition to the paper,
            :meth:`lfsf.solver.LevelSolver.fill_hidden`). δ2 alone, σ = 4, no depth weight
            (fourth session): δ2 MSE at 320×240 `large_motion` 0.144 → 0.030, `slanted`
            0.022 → 0.0033. After every warp it fed back into the flow (640×480 `paper`
            EPE 0.0764 → 0.0809).
        hidden_fill_depth : σ_d of that fill's depth weight exp(−(δ1(q) − δ1(p))²/2σ_d²),
            px per view step at full resolution; 0: none. It keeps the occluder, which is
            nearer, out of the mean. Without it the flow fill took the occluder's motion
            (EPE 2.6–2.7× over 12 scenes). With it (σ = 8, σ_d = 0.1, ninth session;
            geometric means over the scenes of ``compare_peers.py --random 8``, δ1
            unchanged): EPE 0.90×, 0.92×, 0.91× at 160×120, 320×240, 640×480, δ2 0.72×,
            0.64×, 0.70×; δ2 alone is also filled where the searches flag the point
            hidden, and where its flow finds no match at t2
            (:func:`lfsf.estimate._unmatched`: its t2 samples show another point; δ2
            MSE 0.76×, 0.84×, 0.67× over 40 and 64 scenes at 160×120 and 13 at 320×240,
            thirty-eighth session) (:meth:`lfsf.solver.LevelSolver.fill_hidden`'s
            ``flagged``); δ2 and the flow where that flow is lost, its residual above
            what a flow 1 px off would leave (EPE 0.996×, 0.994×, 0.979× on those sets;
            ``hidden``).
        cubic : the values of the samples at their warped positions (W1, W2, J2, §3) by
            Catmull–Rom cubic interpolation over 4 × 4 pixels (an addition to the
            paper); False: bilinear over 2 × 2 pixels, the paper's quadrilinear lookup
            with the views' angular interpolation (MODEL.md §2). The gradients stay the
            central differences of bilinear samples either way; the cubic's own
            derivative amplified the views' noise (σ = 0.02 at 320×240: EPE 4.8× on
            `random-0`). Within a pixel of the border both read bilinearly (clamped). At
            the true motion, bilinear values leave a residual |I2(p + u) − I1(p)| of
            2–2.6× cubic's on the synthetic scenes, a bias that the warps fit; paired
            geometric means of δ1 / δ2 / EPE against bilinear (docs/accuracy.md): 0.94
            / 0.81 / 0.89× over the built-in scenes, `random-0…31` and four receding
            planes at 160×120, 0.97 / 0.97 / 0.94× over `random-32…95`, 0.98 / 1.06 /
            0.94× over 13 scenes at 320×240; with noise of σ = 0.02 on every view 0.95 /
            1.02 / 1.02× (10 scenes at 160×120): for noisy light fields False may serve
            as well.
        texture_theta : θ of the structure–texture split T = I − θ·ROF(I); 0 disables it.
            Higher θ suits real data (HCI antinous BadPix 13.7 % at 0.85, 21.6 % at 0.5)
            but costs accuracy on brightness-constant scenes (``weak_texture`` flow EPE
            0.108 at 0.85, 0.071 at 0.5, 320×240); 0.5 is the measured compromise
            (docs/accuracy.md).
        rof_weight : μ, the ROF fidelity weight (min Σ|∇u| + 1/(2μ) Σ(u − f)²).
        rof_iterations : iterations of the (accelerated) primal–dual ROF solve.
        contrast : the matched images (texture parts) are scaled by one factor so that the
            t1 centre view's mean absolute image gradient is this (0: no scaling); λ is
            then independent of the scene's contrast.
        match_exposure : undo a change of exposure between the two captures (an addition
            to the paper). A flow-only pilot on the grey centre views, box-averaged to
            160–319 px along the longer side, with θ = 0.95 (robust to brightness
            changes), gives correspondences; an L1 fit over them, both ways and weighted
            to flat pixels, gives I1(p) ≈ g·I2(p + u) + b. Where that moves the t2
            intensities by more than EXPOSURE_CHANGE (0.4 % of the range), t2's grey views
            (after any stretch to [0, 1]) become g·L2 + b before they are sampled; below it
            nothing changes (:func:`lfsf.estimate._exposure_change`). Gains beyond three
            stops (g outside [1/8, 8]) are refused, and the progress says so. Views under 48
            px along the shorter side skip it; those under 120 px along the longer side
            are fitted only where their centre views' mean brightness differs by more
            than SMALL_VIEWS_BRIGHTNESS (5 %), and matched only where the fit moves the
            intensities by more than SMALL_VIEWS_CHANGE (3 %): a pilot that small reads
            changes of up to 1.5 % on pairs of one exposure.
            With θ = 0.5 half the structure stays in the matched images, so a gain of 0.99
            on t2 alone took `paper`'s flow EPE 0.067 → 0.094 and 0.95 to 0.34 (160×120).
            A change over part of the view (a glare or a shadow that comes or goes) is
            matched too, by a smooth field added to t2 after the line, where such a field
            explains more than LOCAL_LIGHT_AREA (3 %) of the view, not in thin bands
            only, and the pilot's flow holds (:func:`lfsf.estimate._local_light`; not on
            views under 120 px along the longer side):
            a glare of 0.2 at t2 had taken
            `paper`'s flow EPE 0.059 → 0.218; matched, 0.083.
        tone_curve : match t2 by a tone curve rather than the line where the line leaves
            the intensities bowed (an addition): 16 bands of equal counts, their median
            residuals off the line by more than EXPOSURE_CURVE_MIN (0.3 % of the range)
            and bowing by more than EXPOSURE_CURVE_BOW (0.3 %) across the range; the curve
            runs through the bands' medians. A helper's Lytro pair shifted by (3, 2) px
            with t2^0.8 (a camera's other gamma): flow EPE with `fast` 0.958 → 0.092. Off
            by default: where the pilot's flow is wrong on one object its band of
            intensities strays, and a curve through it cost a helper's scene (s11, ×1.2)
            δ1 / δ2 / EPE 3.1 / 7.1 / 1.5× (1 of 80 pairs given ×1.2 bowed so). With it
            off, a bow found is told in the progress, which names this setting.
        view_gain_sigma : σ (px) of the per-view gain fields (an addition to the paper;
            0: off). A real camera's views of one point differ in brightness (vignetting,
            view-dependent shading). A quick stereo pilot on the t1 light field at about
            160 px gives the disparity; each view, warped to the centre by it, is matched
            to the centre view in brightness by a gain field, the local least-squares
            ratio under a Gaussian of this σ, and multiplied by it at both times where
            the fields change the views by more than 1 % (95th percentile; rendered
            Lambertian scenes stay below it and are left as they are) (:mod:`lfsf.gains`);
            not on views shorter than 40 px (their parallax reads as gains).
            HCI antinous MSE×100 1.95 → 1.76, BadPix 13.1 → 8.4 %; the Lytro scene
            0.0130 → 0.0123; synthetic scenes with vignetting of k = 0.05 (up to 10 %,
            `synth.add_vignetting`) δ1 / δ2 / EPE 0.97 / 0.90 / 0.92× (160×120, 24).
        dark_view_fraction : views whose mean brightness is under this fraction of the
            views' median (at t1 or t2; an addition; 0: off) are dark: a dead camera of
            an array, the black corners or rim another decoder leaves, garbage. Where the
            samples would read one, R is lowered in quarter view steps (not below 1) to
            the largest radius whose samples read none, with a note naming them; a dark
            centre view is told (:func:`lfsf.estimate._dark_views`). A helper's scenes
            with the 32 views outside the 9×9 grid's inscribed circle black: δ1 MSE 6×
            worse with `paper`, 65× with `lytro`; at R = 2.75 as from the whole light
            field. Vignetting is no darkness: views at 0.67 of the centre's brightness
            (k = 0.45) keep R = 4; HCI's and the Lytro scene's views are 0.97–1.01.
    Regulariser: image-driven TGV² (§4)
        alpha0, alpha1 : α0 (on ∇w) and α1 (on Γ(∇x − w)). Where the data is weak a
            ramp of length L costs about 2α0/L per unit of height and a jump off the
            image's edges α1: α0/α1 sets how long a ramp must be before it is cheaper
            than a jump. α0 = 6 (was 2) stopped the bust's disparity from ramping
            down over the wall in HCI antinous (MSE×100 5.0 → 3.6) and, at 320×240,
            took the synthetic gmean δ1 / δ2 / EPE from 0.0021 / 0.038 / 0.065 to
            0.0018 / 0.038 / 0.066 (α0 = 4: 0.0017 / 0.034 / 0.065, HCI 3.9, but
            `large_motion` δ2 0.431 at 160×120 against its bar of 0.419; α0 = 6: 0.388).
            ``alpha0`` holds for δ1 and δ2.
        alpha0_flow : α0 of the flow (u, v) (an addition; the paper has one α0); None
            (the default): ``alpha0``'s (:attr:`flow_alpha0`). An affine motion (a
            rotation, a zoom) is a constant ∇w on the object, whose edge
            costs α0·|∇w|·its outline: α0 = 6 made the flow of an object of radius below
            ~2α0/α1 = 24 px piecewise constant (a disc turning 10°: EPE 0.196;
            α0_flow = 3 / 2 / 1.5: 0.085 / 0.069 / 0.065). Lower values cost the
            disparities through the joint rows: over 21 scenes (the built-in four,
            random-0…3, two other renderers' 13, 160×120) δ1 / δ2 / EPE 1.10 / 1.20 /
            0.86× at 3, 1.09 / 1.11 / 0.69× at 1.5 (geometric means; single ratios
            0.02…5×): by default the flow keeps α0. Try 1.5–3 for turning or zooming
            objects.
        gamma, beta : γ, β of Γ = exp(−γ|∇I|^β) n nᵀ + n⊥ n⊥ᵀ (∇I by forward differences,
            as ∇ of the unknowns).
        flow_edge_weight : the flow's tensor Γ_uv is that of the two-channel guide (I1,
            c·δ̂1) with c this weight, I1 the t1 centre view's luma: depth edges, where
            objects at different depths move differently, let the flow jump too (an
            addition; 0: the luma's Γ_t1, the paper's).
        warp_tensor2 : Γ_t2 (for δ2, a map on the t1 grid) from the t2 centre view
            warped onto the t1 grid by the current flow, I2(p + û), so that its edges
            are where δ2's are (False: the view as it is).
        colour_tensor : on colour light fields, Γ_t1 (δ1's tensor) is Di Zenzo's tensor
            of the t1 centre view's R, G, B channels, n and m² the leading eigenvector
            and eigenvalue of the channels' mean ∇I ∇Iᵀ (an addition; False: the luma's,
            the paper; grey input, and grey views stored as RGB, always take the luma's).
            Edges between colours of like brightness then stop δ1's diffusion too. HCI
            antinous MSE×100 1.998 → 1.915; colour synthetic scenes (paired, gmean
            δ1 / δ2 / EPE) 0.99 / 1.03 / 1.05 at 160×120 on the built-in ones and
            `random-0…7` (`large_motion` EPE 0.230 → 0.330), 0.83 / 0.84 / 0.99 on
            `random-8…23`, 0.83 / 0.99 / 1.01 at 320×240 (built-in and `random-0…3`).
            Γ_t2 (δ2) and Γ_uv (the flow) stay the luma's: colour there as well made
            δ2 worse (docs/accuracy.md).
    Optimisation (§5, §6)
        pyramid_scale : η_s, the size ratio between pyramid levels.
        min_size : the coarsest level's shorter side is at least this many pixels.
        max_levels : an upper bound on the number of levels (0: no bound).
        warps : re-linearisations per level.
        iterations : primal–dual iterations per warp.
        final_iterations : primal–dual iterations of the last warp on the finest level (an
            addition; 0: ``iterations``, the paper's schedule). Where the data term is
            flat (sky, walls, shading) the flow converges slowly, and the last warp's
            state is the result: 200 against 100 gave flow EPE 0.955× (48 scenes at
            160×120, solid textures and photographs; worse by > 5 % on 2) and 0.929× at
            320×240 (16; better on all), δ1 0.98×, for about 20 % more of the finest
            level's iterations.
        carry_duals : the disparities' parts of the TGV duals (y for ∇δ − w, z for ∇w)
            start each level from the coarser level's, upsampled, instead of 0 (MODEL.md
            §6: duals may be reset or upsampled). The slopes of weakly textured surfaces
            then need not be rebuilt a pixel per iteration on the finest level: HCI
            antinous MSE×100 2.32 → 2.00; the synthetic scenes' δ1 / δ2 / EPE 0.96 /
            0.94 / 0.99 at 160×120 (40 scenes), 1.03 / 1.03 / 1.01 at 320×240 (16).
            The flow's duals are reset (carried too, the flow was 4 % worse at 320×240).
        median_radius : radius of the median filter on the flow after each warp (0: off),
            on levels up to 320 px wide; wider levels scale it with their width, up to 3
            (:meth:`lfsf.solver.LevelSolver.median_radius`).
        median_tolerance : τ, px per view step (full resolution): only the window's pixels
            whose δ1 is within τ of the centre pixel's take part in its median, so that a
            window across a depth edge does not mix two objects' flows (an addition; 0: all
            of them, Wedel et al.'s plain median; :mod:`lfsf.kernels.median`). It scales
            with the level. 320×240 flow EPE (τ = 0 → 0.5): `paper` 0.067 → 0.063,
            `large_motion` 0.104 → 0.057 (docs/accuracy.md).
        depth_change_radius : r of a median of the depth change D = δ2 − δ1 at the end
            (an addition; 0: off): δ2 = δ1 + the median of D over the (2r+1)² window's
            pixels whose δ1 is within ``median_tolerance`` of the centre's (all of them
            with a tolerance of 0), its own surface's motion in depth. δ1 is the better
            determined of the two, and a surface's D varies slowly. The radius grows with the width as
            ``median_radius``'s does, up to 3.
        surface_fit : on the finest level, before its last warp and at the end, fit each
            surface's motion (an affine flow and depth change) from its pixels whose flow
            matches the centre views well, and give it to the pixels it explains better,
            the flow by the centre views, then δ2 by the t2 samples (an addition;
            :func:`lfsf.estimate._fit_surface_motion`). The coarse levels blur a surface's
            rim into its neighbour's motion, and where the neighbour is the farther one the
            rim's δ2 then takes the farther surface's disparity at t2 (a plane receding by
            20 %: δ2 MSE 0.0092 → 0.0038). Paired geometric means of δ1 / δ2 / EPE: 0.99 /
            0.77 / 0.93× over the built-in scenes and `random-0…95` at 160×120, 1.00 / 0.87
            / 0.91× over 12 scenes at 320×240 (docs/accuracy.md). Flow only skips it.
        colour_median_radius : r of the last step on colour light fields (an addition;
            0: off; grey input never takes it, nor grey views stored as RGB, see
            ``lfsf.estimate.GREY_CHROMA``): δ1 and δ2 are snapped to the colour
            edges of the t1 centre view where they jump, by the median of their (2r+1)²
            window weighted by colour likeness (:func:`lfsf.kernels.median.guided_median_edges`).
            The estimate spreads the nearer surface over the farther one by a pixel or
            two where their luma matches; their colours often differ. At most 3.
        colour_median_separation : κ of that step: it acts only where the colours of
            the window's two depth groups are apart by more than κ times their spread
            (where both surfaces have the same texture, colour cannot place the edge).
        speckle_radius : r of the very last step (an addition; 0: off; at most 3): δ1
            and δ2 each take the median of their (2r+1)² window where fewer than
            ``lfsf.estimate.SPECKLE_SUPPORT`` (8) of its pixels hold a depth within
            ``SPECKLE_DEPTH`` (0.3 px per view step) of theirs
            (:func:`lfsf.kernels.median.remove_speckles`), a stereo matcher's speckle
            filter: a few pixels at a depth no surface around shares are a stray pick of
            the data. A structure one pixel wide goes with them. Paired geometric means
            of δ1 / δ2 (EPE unchanged): 0.90 / 0.97× over the built-in scenes, `random-0…31`
            and four receding planes at 160×120, 0.95 / 0.95× over `random-32…95`, 0.73 /
            0.79× with photographs on the objects; HCI antinous MSE×100 1.731 → 1.707
            (docs/accuracy.md). Flow only skips it.
        eps : ε added to the preconditioners' denominators.
        step_ratio : c, the balance of primal and dual steps: every τ is multiplied and
            every σ divided by it. The preconditioners' convergence guarantee
            (‖Σ^½ K T^½‖ ≤ 1) holds for any c > 0, and the solution does not depend on
            it, but the speed of convergence does: c < 1 (smaller primal, larger dual
            steps) settled flow-only TGV in fewer iterations (``flow`` preset). 1 is
            Pock & Chambolle's (and the paper's).
        warm_levels : when the estimate starts from a given one (``init`` of
            :func:`lfsf.estimate_scene_flow`, e.g. the previous pair of a sequence), only
            the finest this many levels run (0: all levels, started from it).
    Disparity search (an addition to the paper: see :mod:`lfsf.kernels.search`)
        disparity_search : start each level's disparities from whichever is better, per
            pixel, of the warped estimate and a plane sweep over the samples.
        late_search : fuse the sweep's maps once more on the finest level, before its
            last warp, where the flow does not match the centre views (an addition;
            without ``disparity_search`` it does nothing). Through the cross-time rows (ρ3)
            a wrong flow at an outline drags δ1 and δ2 over the warps to the other surface's depth, which the
            t1 samples alone do not give them; there ties go to the sweep
            (``lfsf.estimate.LATE_SEARCH_MARGIN``), where a surface at the sweep's depth
            lies within 3 px (``LATE_SEARCH_REACH``, ``LATE_SEARCH_DEPTH``). Paired geometric means of δ1 / δ2 /
            EPE: 0.73 / 0.80 / 0.97× over the built-in scenes, `random-0…31` and four
            receding planes at 160×120, 0.88 / 0.86 / 0.99× over `random-32…95`, 0.81 /
            0.86 / 0.99× over 13 scenes at 320×240 (docs/accuracy.md).
        outline_relabel : at the very end, give an outline pixel the whole state (δ1, δ2,
            u, v) of a neighbour within 2 px on the other side of its depth edge where
            that explains both its t1 samples and the centre views better (an addition;
            :func:`lfsf.estimate._relabel_outlines`). An outline pixel whose flow went
            with the neighbouring surface is dragged by ρ3 to that surface's depth, and
            the windowed fusions judge it mostly by its neighbours. A state that puts the
            pixel behind its own must also lower, below 0.8×, the cost over the t1
            samples that the view z-buffers leave visible. Never where the flow matches:
            a stereo pair (t1 = t2) is left as it is. The runs without it against those
            with it (δ1 / δ2 / EPE, geometric means, 160×120, sixty-second session):
            1.12 / 1.06 / 1.006× over the built-in scenes and `random-0…31`, 1.05 / 1.05
            / 1.004× over `random-32…95`, 1.01 / 1.00 / 1.006× over the 23 scenes of
            `scripts/independent_scenes.py` (docs/accuracy.md).
        disparity_range : the sweep covers ±this many px per view step (full resolution).
        search_radius : the sweep's matching costs are averaged over (2r+1)² windows.
        flow_search : likewise for the flow, with a whole-pixel block-matching search of
            the centre views on a coarse level, for motions too large for the pyramid;
            not fused where the point is hidden at t2 (by the searches both ways, or
            by the estimate so far).
        flow_range : the flow search covers at least ±this many px (full resolution).
        flow_range_share : … and at least this share of the views' longer side (0.025:
            ±32 px where it is 1280 px, ±48 at 1920; with flow_range 24, ±24 up to 960).
            A scene's motions in pixels grow with its views: on `paper` at 1920×1080 (flows
            up to 51 px) ±24 lost the fast objects (EPE 0.714), ±48 did not (0.100); a wider
            search also fuses more false matches (`large_motion` there 0.052 → 0.057), so
            the range grows only with the views (:meth:`flow_search_range`), and no
            further than the coarsest pyramid level can search (±64 px there). 0:
            flow_range alone.
    """

    circles: int = 3
    samples: tuple[int, ...] = (1, 8, 8)
    radius: float = 4.0
    whole_circles: bool = False
    lambda1: float = 10.0
    lambda2: float = 10.0
    lambda3: float = 30.0
    lambda3_side: float = 1.0
    occlusion_ratio: float = 0.7
    visibility: bool = True
    occlusion_margin: float = 0.25
    occlusion_reach: int = 3
    hidden_fill_sigma: float = 8.0
    hidden_fill_depth: float = 0.1
    cubic: bool = True
    texture_theta: float = 0.5
    rof_weight: float = 0.125
    rof_iterations: int = 60
    contrast: float = 0.02
    match_exposure: bool = True
    tone_curve: bool = False
    view_gain_sigma: float = 24.0
    dark_view_fraction: float = 0.5
    alpha0: float = 6.0
    alpha1: float = 0.5
    alpha0_flow: float | None = None
    gamma: float = 10.0
    beta: float = 0.7
    flow_edge_weight: float = 0.5
    warp_tensor2: bool = True
    colour_tensor: bool = True
    pyramid_scale: float = 0.5
    min_size: int = 10
    max_levels: int = 0
    warps: int = 5
    iterations: int = 100
    final_iterations: int = 200
    carry_duals: bool = True
    median_radius: int = 2
    median_tolerance: float = 0.5
    depth_change_radius: int = 2
    surface_fit: bool = True
    colour_median_radius: int = 3
    colour_median_separation: float = 1.5
    speckle_radius: int = 3
    eps: float = 1e-6
    step_ratio: float = 1.0
    warm_levels: int = 0
    disparity_search: bool = True
    late_search: bool = True
    outline_relabel: bool = True
    disparity_range: float = 4.0
    search_radius: int = 1
    flow_search: bool = True
    flow_range: float = 24.0
    flow_range_share: float = 0.025

    def __post_init__(self):
        for f in dataclasses.fields(self):
            check = _TYPE_CHECKS.get(f.type)
            if check is not None:
                object.__setattr__(self, f.name, check(f.name, getattr(self, f.name)))
        self.validate()

    # --- construction ----------------------------------------------------------------------

    @classmethod
    def preset(cls, name: str) -> "Params":
        """``paper``: the paper's synthetic setting (M = 3, N = (1, 8, 8), R = 4: 17 views);
        ``fast``: fewer views and iterations; ``lytro``: the paper's Lytro setting
        (M = 2, N = (1, 16)); ``flow``: optical flow of the centre views alone (M = 1),
        quick."""
        if not isinstance(name, str) or name not in PRESETS:
            guess = difflib.get_close_matches(name, list(PRESETS), n=1) if isinstance(name, str) else []
            raise ValueError(f"unknown preset {name!r}{f' (did you mean {guess[0]!r}?)' if guess else ''}: the "
                             f"presets are {', '.join(PRESETS)}")
        return cls(**PRESETS[name])

    @property
    def flow_alpha0(self) -> float:
        """α0 of the flow (u, v): ``alpha0_flow``, or ``alpha0`` where that is None."""
        return self.alpha0 if self.alpha0_flow is None else self.alpha0_flow

    @property
    def flow_only(self) -> bool:
        """One circle (M = 1): the flow of the centre views alone, whose δ1 and δ2 are
        zeros, not estimates (not drawn, nor scored)."""
        return self.circles == 1

    def replace(self, **changes) -> "Params":
        """A copy with some settings changed (validated; a name of no setting refused with
        the nearest names, by ``__init__``: :func:`_init_naming_unknown_settings`)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_toml(cls, path: str | os.PathLike, base: "Params | None" = None, preset: str | None = None) -> "Params":
        """Settings from a TOML file (top-level keys, or a ``[params]`` table; a
        ``preset = "name"`` key picks the base), over ``base`` (default: the preset).
        ``preset``: a preset named elsewhere (``--preset``), the base where the file
        names none; a file naming another is an error rather than silently winning. A
        preset, named in the file or as ``preset``, replaces ``base``.

        ``path`` may also be a result of ``lfsf run`` or ``lfsf batch`` (its folder or its
        ``sceneflow.npz``): the settings it records it was estimated with, complete (no
        preset may be named beside them), so that a result can be estimated again as it
        was."""
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        from lfsf._files import file_name, read_capped

        path = file_name(path, "a TOML file's name")
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such file")
        if path.suffix.lower() == ".npz" or (path.is_dir() and (path / "sceneflow.npz").is_file()):
            return cls._from_result(path, preset)
        if path.is_dir():
            raise ValueError(f"{path}: a folder, not a TOML file of settings (nor a result's, with a "
                             "sceneflow.npz)")
        try:
            # TOML is UTF-8 whatever the locale (Windows' would be cp1252); a BOM is let through
            data = tomllib.loads(read_capped(path, MAX_TOML_BYTES, "a TOML file of settings").decode("utf-8-sig"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not valid TOML ({exc})") from None
        except RecursionError:
            raise ValueError(f"{path}: not valid TOML of settings (nested too deeply to read)") from None
        if "params" in data:
            outside = sorted(k for k in data if k not in ("params", "preset"))
            tables = [k for k in outside if isinstance(data[k], dict)]
            if tables:
                raise ValueError(f"{path}: unknown table{'s' if len(tables) > 1 else ''} "
                                 f"{', '.join(f'[{k}]' for k in tables)}; the settings go in [params] (or all "
                                 "at the top level)")
            if outside:      # they would be dropped without a word
                raise ValueError(f"{path}: settings both in [params] and at the top level "
                                 f"({', '.join(outside)}); put them all in one place")
            table = data["params"]
            if not isinstance(table, dict):
                raise ValueError(f"{path}: [params] must be a table of settings, got {table!r}")
            # preset = "…" at the top level beside [params] picks the base as it does inside
            if "preset" in data and "preset" in table and data["preset"] != table["preset"]:
                raise ValueError(f"{path}: preset = {data['preset']!r} at the top level but {table['preset']!r} "
                                 "in [params]; name it in one place")
            data = {**table, **({"preset": data["preset"]} if "preset" in data else {})}
        else:
            tables = sorted(k for k in data if isinstance(data[k], dict))
            if tables:   # ([param] for [params]: read as one setting named "param")
                raise ValueError(f"{path}: unknown table{'s' if len(tables) > 1 else ''} "
                                 f"{', '.join(f'[{k}]' for k in tables)}; the settings go in [params] (or all "
                                 "at the top level)")
        if not isinstance(data, dict):
            raise ValueError(f"{path}: [params] must be a table of settings, got {data!r}")
        data = dict(data)
        named = data.pop("preset", None)
        if named is not None and not isinstance(named, str):
            raise ValueError(f"{path}: preset must be a name in quotes ({', '.join(PRESETS)}), got {named!r}")
        if named is not None and named not in PRESETS:   # (a typo, before any conflict with --preset)
            try:
                cls.preset(named)
            except ValueError as exc:
                raise ValueError(f"{path}: {exc}") from None
        if named is not None and preset is not None and named != preset:
            raise ValueError(f"{path}: preset = {named!r} here, but preset {preset!r} was given too "
                             "(--preset); name it in one place")
        named = preset if named is None else named
        try:
            params = cls.preset(named) if named is not None else (base or cls())
            return params.replace(**data)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{path}: {exc}") from None

    @classmethod
    def recorded(cls, settings: dict) -> "Params":
        """The settings that a result records (``Params.as_dict()`` in its
        ``sceneflow.npz``), to estimate it again as it was: a setting added since it was
        written takes the value that does what that version did (:data:`BEFORE_ADDED`), or
        else its default."""
        return cls().replace(**{**{k: v for k, v in BEFORE_ADDED.items() if k not in settings}, **settings})

    @classmethod
    def _from_result(cls, path: Path, preset: str | None) -> "Params":
        """The settings a result records (:meth:`from_toml` on a result's folder or
        ``sceneflow.npz``)."""
        from lfsf.evaluate import recorded_settings

        settings = recorded_settings(path)
        if settings is None:
            raise ValueError(f"{path}: records no settings of lfsf (expected a result of lfsf run or batch: its "
                             "folder or its sceneflow.npz, or a TOML file)")
        if preset is not None:
            raise ValueError(f"{path}: a result's recorded settings are complete; --preset {preset} beside them "
                             "would be ignored: leave it out")
        try:
            return cls.recorded(settings)
        except (ValueError, TypeError) as exc:  # (a result of another version's settings)
            raise ValueError(f"{path}: its recorded settings are not this version's: {exc}") from None

    # --- derived ---------------------------------------------------------------------------

    def validate(self) -> None:
        """Ranges of the settings (their types are checked on construction). The upper
        bounds keep a mistyped value from hanging the estimator or exhausting memory; each
        is far above what the presets and the measurements use."""
        def need(ok, message):
            if not ok:
                raise ValueError(f"bad parameter: {message}")

        # real settings in float32 with room to spare: the kernels compute in float32, and
        # λ = 1e39, α = 1e308 or step_ratio = 1e-308 made every map NaN without an error
        # the real settings that 0 does not suit either (refused below): their message
        # offers no 0
        positive = ("alpha0", "alpha1", "rof_weight", "eps", "step_ratio", "pyramid_scale", "disparity_range",
                    "flow_range")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "radius" and self.circles > 1:  # (its own range, below)
                continue
            if f.type == "float" and value != 0:
                need(MIN_REAL <= abs(value) <= MAX_REAL,
                     f"{f.name} must be {'positive and' if f.name in positive else '0 or'} of magnitude "
                     f"{MIN_REAL:g}…{MAX_REAL:g}, got {value:g}")
        need(1 <= self.circles <= MAX_SAMPLES,
             f"circles (M) must be in 1…{MAX_SAMPLES}, got {shown_number(self.circles)}")
        need(len(self.samples) == self.circles,
             f"samples (N_i) must give one count per circle: M = {self.circles}, N = {self.samples} (set "
             f"circles = {len(self.samples)} with these samples)")
        need(self.samples[0] == 1,
             f"samples: the first circle is the centre view, N_0 must be 1, got {self.samples[0]}")
        need(all(n >= 1 for n in self.samples), f"samples: every N_i must be at least 1, got {self.samples}")
        # every sample holds ~90 bytes per pixel in the solver (data-term rows, duals,
        # z-buffers, both sample stacks): 256 samples take ~7 GB at 640×480
        need(sum(self.samples) <= MAX_SAMPLES,
             f"samples (N_i) may hold at most {MAX_SAMPLES} positions in all, got {sum(self.samples)}")
        # side samples within a few hundredths of a view step of the centre see no
        # parallax: every A1 = −φ·∇W1 ≈ 0, and δ came out 0 without a word (R = 1e-9)
        need(MIN_RADIUS <= self.radius <= MAX_REAL or self.circles == 1,
             f"radius R must be {MIN_RADIUS}…{MAX_REAL:g} view steps (nearer the centre the side samples see "
             f"too little parallax; a grid of views that allows less than R asked uses less), got {self.radius:g}")
        for name in ("lambda1", "lambda2", "lambda3", "lambda3_side", "alpha0", "alpha1", "gamma", "beta",
                     "rof_weight", "eps"):
            value = getattr(self, name)
            need(value >= 0, f"{name} must be a finite number {'> 0' if name in positive else '≥ 0'}, got {value}")
        for name in ("alpha0", "alpha1"):
            need(getattr(self, name) > 0, f"{name} must be positive, got {getattr(self, name)}")
        need(self.alpha0_flow is None or MIN_REAL <= self.alpha0_flow <= MAX_REAL,
             f"alpha0_flow must be positive and of magnitude {MIN_REAL:g}…{MAX_REAL:g} (or None: alpha0's), "
             f"got {self.alpha0_flow}")
        need(self.rof_weight > 0, f"rof_weight (μ) must be positive, got {self.rof_weight}")
        need(self.eps > 0, f"eps (ε) must be positive (the preconditioners divide by it), got {self.eps}")
        need(self.step_ratio > 0, f"step_ratio must be positive, got {self.step_ratio}")
        need(self.flow_edge_weight >= 0, f"flow_edge_weight must be ≥ 0, got {self.flow_edge_weight}")
        # spread_hidden walks a (2r+1)² window per pixel, every warp
        need(0 <= self.occlusion_reach <= MAX_OCCLUSION_REACH,
             f"occlusion_reach must be in 0…{MAX_OCCLUSION_REACH} px, got {self.occlusion_reach}")
        # fill_hidden_motion walks a (6σ+1)² window per hidden pixel
        need(0 <= self.hidden_fill_sigma <= MAX_HIDDEN_FILL_SIGMA,
             f"hidden_fill_sigma must be in [0, {MAX_HIDDEN_FILL_SIGMA:g}] px, got {self.hidden_fill_sigma}")
        need(self.hidden_fill_depth >= 0, f"hidden_fill_depth must be ≥ 0, got {self.hidden_fill_depth}")
        need(self.occlusion_margin >= 0, f"occlusion_margin must be ≥ 0, got {self.occlusion_margin}")
        need(0 <= self.occlusion_ratio < 1, f"occlusion_ratio must be in [0, 1), got {self.occlusion_ratio}")
        need(self.contrast >= 0, f"contrast must be ≥ 0, got {self.contrast}")
        need(0 <= self.view_gain_sigma <= MAX_VIEW_GAIN_SIGMA,
             f"view_gain_sigma must be in [0, {MAX_VIEW_GAIN_SIGMA:g}] px, got {self.view_gain_sigma}")
        need(0 <= self.texture_theta <= 1, f"texture_theta (θ) must be in [0, 1], got {self.texture_theta}")
        need(0 <= self.dark_view_fraction < 1,
             f"dark_view_fraction must be in [0, 1), got {self.dark_view_fraction}")
        need(0 < self.pyramid_scale < 1, f"pyramid_scale (η_s) must be in (0, 1), got {self.pyramid_scale}")
        need(4 <= self.min_size <= MAX_MIN_SIZE,
             f"min_size must be in 4…{MAX_MIN_SIZE} px, got {shown_number(self.min_size)}")
        # run time grows linearly with these; the presets use 3–5 warps of 20–100
        # iterations and 30–60 ROF iterations
        for name, most in (("warps", MAX_WARPS), ("iterations", MAX_ITERATIONS)):
            value = getattr(self, name)
            need(1 <= value <= most, f"{name} must be in 1…{most}, got {value}")
        need(0 <= self.final_iterations <= MAX_ITERATIONS,
             f"final_iterations must be in 0…{MAX_ITERATIONS} (0: as iterations), got {self.final_iterations}")
        need(0 <= self.rof_iterations <= MAX_ITERATIONS,
             f"rof_iterations must be in 0…{MAX_ITERATIONS}, got {self.rof_iterations}")
        for name in ("max_levels", "warm_levels"):
            value = getattr(self, name)
            need(0 <= value <= MAX_LEVELS, f"{name} must be in 0…{MAX_LEVELS}, got {shown_number(value)}")
        need(0 <= self.median_radius <= 3, f"median_radius must be in 0…3, got {self.median_radius}")
        need(self.median_tolerance >= 0, f"median_tolerance must be ≥ 0, got {self.median_tolerance}")
        need(0 <= self.depth_change_radius <= 3,
             f"depth_change_radius must be in 0…3, got {self.depth_change_radius}")
        need(0 <= self.colour_median_radius <= 3,
             f"colour_median_radius must be in 0…3, got {self.colour_median_radius}")
        need(self.colour_median_separation >= 0,
             f"colour_median_separation must be ≥ 0, got {self.colour_median_separation}")
        need(0 <= self.speckle_radius <= 3, f"speckle_radius must be in 0…3, got {self.speckle_radius}")
        # the sweep's cost volumes hold 4·R·range + 1 candidates per pixel (R = 4, ±32:
        # 513, 1.3 GB at 640×480)
        need(0 < self.disparity_range <= MAX_DISPARITY_RANGE,
             f"disparity_range must be in (0, {MAX_DISPARITY_RANGE:g}] px per view step, got {self.disparity_range}")
        need(0 <= self.search_radius <= 5, f"search_radius must be in 0…5, got {self.search_radius}")
        # the block matching tries (2n+1)² shifts per pixel, n the range on the search
        # level; past what the coarsest level can shrink, n grows with the range
        need(0 < self.flow_range <= MAX_FLOW_RANGE,
             f"flow_range must be in (0, {MAX_FLOW_RANGE:g}] px, got {self.flow_range}")
        need(0 <= self.flow_range_share <= MAX_FLOW_RANGE_SHARE,
             f"flow_range_share must be in 0…{MAX_FLOW_RANGE_SHARE:g} (of the views' longer side), got "
             f"{self.flow_range_share}")

    def flow_search_range(self, size: tuple[int, int]) -> float:
        """The flow search's range in full-resolution px for views of ``size`` (h, w):
        ±max(flow_range, flow_range_share × the longer side), at most MAX_FLOW_RANGE."""
        return min(MAX_FLOW_RANGE, max(self.flow_range, self.flow_range_share * max(size)))

    def sample_offsets(self, grid: tuple[int, int]) -> tuple[np.ndarray, float]:
        """The angular offsets φ_ij = r_i (cos s_ij, sin s_ij) in view steps, centre first,
        and the radius R actually used (:meth:`grid_radius`: as far as every sample stays
        within the grid; 0 with one circle, which samples the centre view alone). The angles
        s_ij = s_0 + 2πj / N_i start on the grid's long axis: s_0 = 0 (along the rows), or
        90° on a grid taller than wide where a circle's samples turned by 90° are not the
        same set (N_i not a multiple of 4: samples = [1, 2] on a vertical rig). With
        ``whole_circles`` the inner circles lie on whole view steps where r_i = R·i/(M − 1)
        is not one (:func:`_on_whole_views`: R = 3 takes r_1 = 2, not 1.5)."""
        rows, cols = (grid, grid) if np.isscalar(grid) else grid    # (a square grid as one number)
        radius = self.grid_radius((rows, cols))
        phis = [(0.0, 0.0)]
        if radius > 0:
            for r, angles in self._circles((rows, cols), radius, half=((cols - 1) / 2.0, (rows - 1) / 2.0)):
                phis.extend((r * math.cos(s), r * math.sin(s)) for s in angles)
        out = np.asarray(phis, dtype=np.float32)
        out[np.abs(out) < 1e-6] = 0.0
        return out, radius

    def grid_radius(self, grid: tuple[int, int]) -> float:
        """The sampling radius R used on a rows × cols grid of views: ``radius``, or less
        where a sample would fall outside the grid (each axis on its own: a sample along
        the rows needs only columns of views, so a 1×N rig takes samples = [1, 2]); 0 with
        one circle, or where no R fits (a sample off the axis of a one-row grid)."""
        rows, cols = (grid, grid) if np.isscalar(grid) else grid
        if rows < 1 or cols < 1:  # (R had come out negative)
            raise ValueError(f"a grid of views has at least one row and one column, got {rows}×{cols}")
        if self.circles <= 1:
            return 0.0
        half = ((cols - 1) / 2.0, (rows - 1) / 2.0)  # the grid's half extents along x and y
        limit = float(self.radius)
        for r, angles in self._circles((rows, cols), 1.0):
            for s in angles:
                for extent, component in zip(half, (math.cos(s), math.sin(s))):
                    if abs(component) > 1e-6:
                        limit = min(limit, extent / (r * abs(component)))
        return limit

    def _circles(self, grid: tuple[int, int], radius: float, half: tuple[float, float] | None = None):
        """(r_i, the angles s_ij) of the circles i = 1 … M − 1 at sampling radius R; with
        the grid's ``half`` extents (x, y), the inner circles on whole view steps
        (:func:`_on_whole_views`) where ``whole_circles``."""
        rows, cols = grid
        turned = rows > cols and any(n % 4 for n in self.samples[1:])
        start = math.pi / 2 if turned else 0.0
        inner = 0.0  # (the last circle's radius, as placed)
        for i in range(1, self.circles):
            n = self.samples[i]
            r = radius * i / (self.circles - 1)
            angles = [start + 2.0 * math.pi * j / n for j in range(n)]
            if half is not None and self.whole_circles and i < self.circles - 1:
                r = _on_whole_views(r, (inner, radius * (i + 1) / (self.circles - 1)), angles, half)
            inner = r
            yield r, angles

    def as_dict(self) -> dict:
        """Every setting by name (what ``sceneflow.npz`` records; ``Params(**d)`` makes it
        again)."""
        return dataclasses.asdict(self)

    def key(self) -> str:
        """A name of these settings that is the same in every process and every run of
        Python, for a sweep's stored results (``hash()`` is not: Python hashes None, and
        text, anew in each process): the first 16 hex digits of the SHA-256 of the
        settings as sorted JSON. Equal Params have equal keys."""
        import hashlib
        import json

        text = json.dumps(self.as_dict(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]

    def __repr__(self) -> str:
        """The settings that differ from the defaults (the `paper` preset), as a call
        that makes the same Params: ``Params()`` for `paper`; all of them (55) made a repr
        of about 1000 characters."""
        changed = ", ".join(f"{f.name}={getattr(self, f.name)!r}" for f in dataclasses.fields(self)
                            if getattr(self, f.name) != f.default)
        return f"Params({changed})"


def _on_whole_views(r: float, between: tuple[float, float], angles, half: tuple[float, float]) -> float:
    """An inner circle's radius r_i = R·i/(M − 1) moved to the nearest whole view step
    (halves up), where that is at least 1, lies strictly ``between`` the circle inside
    (as placed) and the next one's r_(i+1) (two circles on one radius would sample the
    same views twice), and keeps every sample within the grid (``half``: its half extents
    along x and y); else r_i. Between two views a sample is their blend, two copies of
    the scene δ pixels apart: at R = 3 (a 7×7 grid, or ``radius = 3``) the paper's
    r_1 = 1.5 biased the background of HCI antinous (|δ| ≈ 3) by +0.06, BadPix(0.07)
    27.6 % against 7.8 % at R = 4 (r_1 = 2); at r_1 = 2 it is 13.2 % (r_1 = 1: 13.0 %),
    MSE×100 1.99 → 1.72 (``Params.whole_circles``)."""
    whole = math.floor(r + 0.5)
    if not (whole >= 1 and between[0] < whole < between[1]):
        return r
    for s in angles:
        for extent, component in zip(half, (math.cos(s), math.sin(s))):
            if abs(whole * component) > extent + 1e-6:
                return r
    return float(whole)


def _nearest_names(name: str, names) -> list[str]:
    """The names nearest to ``name`` (difflib's measure, 0.6 at least), all those equally
    near: ``lamda3`` → lambda3, ``lambda`` → lambda1, lambda2 and lambda3."""
    scores = {n: difflib.SequenceMatcher(None, name, n).ratio() for n in difflib.get_close_matches(name, names, n=5)}
    best = max(scores.values(), default=0.0)
    return sorted(n for n, score in scores.items() if score >= best - 1e-9)


# Upper bounds of the settings that size buffers or loops (:meth:`Params.validate`).
MAX_SAMPLES = 256
#: The least sampling radius R (view steps) with side samples, the half extent of a 2×2
#: grid: nearer the centre they see too little parallax for δ (the presets use 4 on a 9×9
#: grid). The `paper` scene at 160×120 on a 9×9 grid, δ1 MSE with the `paper` preset:
#: 0.0031 at R = 4, 0.096 at 0.5; with `fast`: 0.0024, 0.086, 0.85 at 0.3, 1.64 at 0.25.
MIN_RADIUS = 0.5
#: The magnitudes a real setting may have (or 0): within float32 (1.2e-38…3.4e38) with
#: room for the products the kernels form. `fast` at 48×40 gave finite maps with every
#: real setting at 1e-12 and at 1e12 that its own range allows, but flow_edge_weight at
#: 1e12 (fine at 1e9).
MIN_REAL = 1e-12
MAX_REAL = 1e9
MAX_OCCLUSION_REACH = 32
MAX_HIDDEN_FILL_SIGMA = 64.0
#: The gain fields are blurred on the pilot's reduced views with a kernel of 3σ: beyond
#: this they are one gain per view.
MAX_VIEW_GAIN_SIGMA = 256.0
MAX_WARPS = 1000
MAX_ITERATIONS = 100_000
#: max_levels' and warm_levels' bound, and min_size's (px): far beyond any pyramid (one of
#: η_s = 0.99 over 8192 px has some 700 levels); 1e300 had been taken, its 300 digits shown.
MAX_LEVELS = 10_000
MAX_MIN_SIZE = 1 << 16
MAX_DISPARITY_RANGE = 32.0
MAX_FLOW_RANGE = 512.0
#: Settings added since results were first recorded, each with the value that does what
#: the versions before it did, where its default does not (:meth:`Params.recorded`): a
#: result written before flow_range_share searched ±flow_range at any size.
BEFORE_ADDED = {"flow_range_share": 0.0}
#: flow_range_share's bound: a quarter of the longer side already searches most of a level.
MAX_FLOW_RANGE_SHARE = 0.25


def _refuse_unknown(settings: Mapping[str, Any]) -> None:
    """A ValueError for names in ``settings`` that are no setting of :class:`Params`,
    with the nearest names ("did you mean lambda1?")."""
    names = [f.name for f in dataclasses.fields(Params)]
    unknown = sorted(set(settings) - set(names))
    if unknown:
        # (the first few, each cut short: a file of 200 000 names had been a message of
        # 1.7 MB after 14 s of guessing)
        shown = [k if len(k) <= 40 else k[:39] + "…" for k in unknown[:MAX_UNKNOWN_SHOWN]]
        more = f" and {len(unknown) - len(shown)} more" if len(unknown) > len(shown) else ""
        guesses = {k: _nearest_names(k, names) for k in shown}
        meant = [f"{k}: did you mean {' or '.join(guess)}?" for k, guess in guesses.items() if guess]
        # (the 50-odd names only where some name has no near one: a line of 900 characters)
        known = "" if all(guesses.values()) else f"; known: {', '.join(names)}"
        raise ValueError(f"unknown parameter(s) {', '.join(shown)}{more}"
                         + (f" ({'; '.join(meant)})" if meant else "") + known)


#: The longest TOML file of settings read (a named pipe is read; /dev/zero is not for ever).
MAX_TOML_BYTES = 16 << 20

#: Unknown settings named in an error, at most.
MAX_UNKNOWN_SHOWN = 8


def _init_naming_unknown_settings(init):
    """The dataclass's ``__init__`` with a setting of no such name refused as
    :meth:`Params.replace` and TOML files refuse it, with the nearest names: ``Params(
    lamda1=3)`` had been Python's TypeError, without a hint."""
    @functools.wraps(init)
    def checked(self, *args, **kwargs) -> None:
        _refuse_unknown(kwargs)
        init(self, *args, **kwargs)

    return checked


Params.__init__ = _init_naming_unknown_settings(Params.__init__)  # type: ignore[method-assign]


def _bad(name: str, expected: str, value) -> ValueError:
    return ValueError(f"bad parameter: {name} must be {expected}, got {value!r} ({type(value).__name__})")


def _whole(name: str, value) -> int:
    """An int setting: an int, or a float with no fraction (TOML's ``3.0``;
    :func:`lfsf._errors.whole`)."""
    number = whole(value)
    if number is None:
        raise _bad(name, "a whole number", value)
    return number


def _real(name: str, value) -> float:
    """A float setting: a finite int or float."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        try:
            number = float(value)
        except OverflowError:  # an int past float's range
            number = math.inf
        if math.isfinite(number):
            return number
    raise _bad(name, "a finite number", value)


def _flag(name: str, value) -> bool:
    """A switch: exactly true or false (a string such as "false" would read as true)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise _bad(name, "true or false", value)


def _counts(name: str, value) -> tuple[int, ...]:
    """``samples``: a list or tuple of whole numbers (a string or one number is none)."""
    if isinstance(value, np.ndarray) and value.ndim == 1:
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        try:
            return tuple(_whole(name, n) for n in value)
        except ValueError:
            pass
    raise _bad(name, "a list of whole numbers, one per circle", value)


#: the check of each field's annotated type (``from __future__ import annotations``: names)
_TYPE_CHECKS = {"int": _whole, "float": _real, "bool": _flag, "tuple[int, ...]": _counts,
                "float | None": lambda name, value: None if value is None else _real(name, value)}


_PRESETS: dict[str, dict] = {
    "paper": {},
    # (ROF with the default 60 steps since the forty-third session: with 30, unconverged,
    # the structure part's blurred edges left a halo in the texture that moved with the
    # nearer surface; HCI antinous MSE×100 11.85 → 4.21, 20 synthetic scenes at 160×120
    # δ1 / δ2 / EPE 0.93 / 0.86 / 0.98×, for 3 % more time at 640×480)
    # (the view gains since the fifty-first session: without them a helper's vignetting of
    # k = 0.1 made δ1 10× worse, k = 0.3 made it noise; HCI antinous at half size MSE×100
    # 10.17 → 4.57, the Lytro scene 0.0221 → 0.0212 px from EPINET; clean renders as before)
    "fast": {"circles": 2, "samples": (1, 8), "warps": 3, "iterations": 30, "final_iterations": 0},
    "lytro": {"circles": 2, "samples": (1, 16)},
    # optical flow of the centre views alone (M = 1): 5 warps of 20 iterations, with
    # steps balanced towards the duals (docs/benchmarks.md: a lower EPE than OpenCV's
    # DualTVL1 on every synthetic scene at 640×480, and faster on `paper`). 5 warps, not
    # 3, since the forty-fourth session: EPE 0.92× on 24 scenes at 160×120, 0.93× on 24
    # unseen ones, 0.90× on the built-in four at 320×240, and a fine texture shifted
    # (5, 5) px as a whole 2.2 px → 0.004 (`scripts/fine_textures.py`), for a quarter
    # more time (640×480 `paper` 1.27 → 1.60 s, OpenCV 1.83 s in the same run)
    "flow": {"circles": 1, "samples": (1,), "warps": 5, "iterations": 20, "final_iterations": 0,
             "rof_iterations": 30, "step_ratio": 0.25},
}
#: The presets by name, read-only (a setting changed here had changed every later
#: ``Params.preset`` in the process, and in its forked workers but not its spawned ones).
PRESETS: Mapping[str, Mapping[str, Any]] = MappingProxyType({name: MappingProxyType(settings)
                                                            for name, settings in _PRESETS.items()})
