"""``hard``: Williams (1978) shadow map from the light's center, the baseline.

Steps: (1) :func:`fit_light_view` + :func:`build_shadow_map` — occluder depths from the light
center through the shared rasterizer; (2) :func:`shadow_lookup` — per eye pixel, project into the
map and compare depths with constant + slope-scaled bias (in texels, see ``shadowmap.py``), with
optional percentage-closer filtering over (2*pcf+1)^2 texels. V is 0 or 1 (fractional with PCF):
a point light at the area light's center, for either light shape.
"""

from __future__ import annotations

from .base import Method, MethodOutput, Param, register
from .shadowmap import build_shadow_map, fit_light_view, lookup_points


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

    def run(self, ctx, map_size, bias, slope_bias, pcf):
        pts, nrm, idx = ctx.points()
        with ctx.timer.phase("shadow_map"):
            view = fit_light_view(ctx.scene, map_size)
            smap = build_shadow_map(ctx.scene, view)
        with ctx.timer.phase("eye_pass"):
            v = lookup_points(smap, pts, nrm, bias, slope_bias, pcf)
            out = ctx.scatter(v, idx)
        stats = {"map_size": map_size, "map_coverage": float((smap.tri_id >= 0).mean())}
        return MethodOutput(out, stats)
