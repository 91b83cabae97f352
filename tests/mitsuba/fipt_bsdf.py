"""fipt's BRDF as a Mitsuba 3 BSDF plugin, `<bsdf type="fipt">`, for validation renders of an
export: with it, a Mitsuba render differs from fipt's own only by the export's textures and by
Monte Carlo noise, which separates those from the BRDF mapping's error (`principled`).

    f = k_d/π + D·F·G_s/4,  k_d = a(1 − m),  k_s = 0.04(1 − m) + a·m
    D: GGX with α = σ²;  F = k_s + (1 − k_s)(1 − v·h)⁵;  G_s = 1/((n·v(1−k)+k)(n·l(1−k)+k)), k = (σ+1)²/8

Parameters as `principled`'s: `base_color`, `roughness`, `metallic` (textures). One-sided: wrap
it in `twosided`. Sampling: cosine or GGX (visible normals) by the lobes' reflectance luminance.
`register()` after `mi.set_variant`.
"""
import drjit as dr
import mitsuba as mi


class FiptBSDF(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.base_color = props.get_texture('base_color', 0.5)
        self.roughness = props.get_texture('roughness', 0.5)
        self.metallic = props.get_texture('metallic', 0.0)
        self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide,
                             mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0] | self.m_components[1]

    def _params(self, si, active):
        return (self.base_color.eval(si, active), self.roughness.eval_1(si, active),
                self.metallic.eval_1(si, active))

    @staticmethod
    def _diffuse_share(a, m):
        wd = mi.luminance(a * (1 - m))
        ws = mi.luminance(0.04 * (1 - m) + a * m)
        return dr.select(wd + ws > 0, wd / (wd + ws), 0.5)

    @staticmethod
    def _ggx(s):
        return mi.MicrofacetDistribution(mi.MicrofacetType.GGX, dr.maximum(s * s, 1e-4), True)

    def eval(self, ctx, si, wo, active=True):
        a, s, m = self._params(si, active)
        ci, co = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        active = active & (ci > 0) & (co > 0)
        h = dr.normalize(si.wi + wo)
        a2 = dr.square(dr.maximum(s * s, 1e-4))
        d = a2 / (dr.pi * dr.square(dr.square(h.z) * (a2 - 1) + 1))
        k = dr.square(s + 1) / 8
        g = 1 / dr.maximum((ci * (1 - k) + k) * (co * (1 - k) + k), 1e-12)
        kd = a * (1 - m)
        ks = 0.04 * (1 - m) + a * m
        f = ks + (1 - ks) * dr.power(1 - dr.clip(dr.dot(si.wi, h), 0, 1), 5)
        v = (kd * dr.inv_pi + d * f * g / 4) * co
        return dr.select(active & dr.isfinite(v), v, 0.0)

    def pdf(self, ctx, si, wo, active=True):
        a, s, m = self._params(si, active)
        active = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
        pd = self._diffuse_share(a, m)
        h = dr.normalize(si.wi + wo)
        p_spec = self._ggx(s).pdf(si.wi, h) / dr.maximum(4 * dr.abs_dot(wo, h), 1e-12)
        p = pd * mi.warp.square_to_cosine_hemisphere_pdf(wo) + (1 - pd) * p_spec
        return dr.select(active & dr.isfinite(p), p, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        a, s, m = self._params(si, active)
        pd = self._diffuse_share(a, m)
        h, _ = self._ggx(s).sample(si.wi, sample2)
        diffuse = sample1 < pd
        wo = dr.select(diffuse, mi.warp.square_to_cosine_hemisphere(sample2), mi.reflect(si.wi, h))
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.eta = 1.0
        bs.sampled_component = dr.select(diffuse, mi.UInt32(0), mi.UInt32(1))
        bs.sampled_type = dr.select(diffuse, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                    mi.UInt32(+mi.BSDFFlags.GlossyReflection))
        bs.pdf = self.pdf(ctx, si, wo, active)
        value = self.eval(ctx, si, wo, active)
        ok = active & (bs.pdf > 0) & (mi.Frame3f.cos_theta(wo) > 0) & dr.all(dr.isfinite(wo))
        w = value / dr.select(bs.pdf > 0, bs.pdf, 1.0)
        return bs, dr.select(ok & dr.isfinite(w), w, 0.0)

    def eval_diffuse_reflectance(self, si, active=True):
        a, _, m = self._params(si, active)
        return a * (1 - m)

    def traverse(self, callback):
        pass

    def parameters_changed(self, keys):
        pass

    def to_string(self):
        return 'FiptBSDF[]'


def register():
    mi.register_bsdf('fipt', lambda props: FiptBSDF(props))
