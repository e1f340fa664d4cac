"""``hard``: Williams (1978) shadow map from the light's center, the baseline.

:func:`fit_light_view` + :func:`build_shadow_map` render the occluders' depths from the light
center through the shared rasterizer; :func:`lookup_image` compares each eye pixel's depth with
constant + slope-scaled bias in texels (``shadowmap.py``), with optional PCF, straight over the
eye G-buffer. V is 0 or 1 (fractional with PCF): a point light at the area light's center, for
either light shape.

Steps, parameters and known limits: ``docs/methods/hard.md``.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .base import Method, MethodOutput, Param, register
from .shadowmap import build_shadow_map, fit_light_view, lookup_image


@register
class Hard(Method):
    name = "hard"
    light_shapes = ("rect", "sphere")
    summary = "shadow map from the light center (+ optional PCF): hard shadows, the baseline"
    paper = "Williams 1978"
    light_view = True  # maps from the light's centre (limits: softshadows.limits)
    params = (
        Param("map_size", 1024, "shadow map resolution (square)", min=16, max=16384),
        Param("bias", 1.0, "constant depth bias, in texels at the receiver", min=0.0),
        Param("slope_bias", 1.0, "slope-scaled bias: texels x tan(angle to light)", min=0.0),
        Param("pcf", 0, "percentage-closer filtering radius in texels (0 = off)", min=0, max=16),
    )

    #: what `softshadows pareto` sweeps (Method.sweep)
    sweep: ClassVar = {"map_size": [256, 512, 1024, 2048], "pcf": [0, 2]}

    def run(self, ctx, map_size, bias, slope_bias, pcf):
        with ctx.timer.phase("shadow_map"):
            view = fit_light_view(ctx.scene, map_size)
            smap = build_shadow_map(ctx.scene, view, tri=False)  # (the faces are never read)
        with ctx.timer.phase("eye_pass"):
            g = ctx.eye
            out = lookup_image(smap, g.position, g.normal, g.mask, bias, slope_bias, pcf)
        # a count of the texels an occluder covers (the depth is +inf elsewhere), not a mean (same
        # value; the mean over a float copy of the map cost ~1 ms a frame)
        stats = {"map_size": map_size, "map_coverage": np.count_nonzero(smap.depth < np.inf) / smap.depth.size}
        return MethodOutput(out, stats)
