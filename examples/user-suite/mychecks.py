"""A user's Mitsuba BSDF, registered from Python, and the checks that gate it.

``powercosine`` is a glossy lobe around the normal, p(ω) = (e + 1)/(2π) cos^e θ,
sampled by inversion: cos θ = u^(1/(e+1)). Each θ_i gets two checks: χ² of the draws
against ``pdf`` (``check_sampler``), and the pdf and weight ``sample`` returns with each
draw against ``pdf`` and ``eval / pdf`` (``check_pdf_consistency``). Two planted,
realistic bugs: with ``bug=True`` the sampler uses the exponent e + 1 (an off-by-one
between the sampler and its pdf: χ² fails); with ``pdf_bug=True`` ``sample`` returns the
density of (cos θ, φ/2π), (e + 1) cos^e θ, without the Jacobian 1/(2π), while its draws
and weight stay right (only the consistency check fails: an integrator's MIS weights
would read the wrong pdf). ``suite`` checks the correct plugin (`mcverify check`
passes); ``planted`` and ``planted_pdf`` check the buggy ones (exit 1).
"""

import drjit as dr
import mcverify as mv
from mcverify.gate import mitsuba as mvm
from mcverify.gate.suites import Check

mi = mvm.mi()   # Mitsuba in the gate's variant: register plugins in it


class PowerCosine(mi.BSDF):
    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        self.e = props.get("exponent", 4.0)
        self.bug = props.get("bug", False)
        self.pdf_bug = props.get("pdf_bug", False)
        self.m_flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        self.m_components = [self.m_flags]

    def _pdf(self, si, wo):
        cos_i, cos_o = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        p = (self.e + 1.0) / (2.0 * dr.pi) * dr.power(dr.maximum(cos_o, 0.0), self.e)
        return dr.select((cos_i > 0) & (cos_o > 0), p, 0.0)

    def sample(self, ctx, si, sample1, sample2, active=True):
        e = self.e + (1.0 if self.bug else 0.0)           # the planted bug
        cos_t = dr.power(sample2.x, 1.0 / (e + 1.0))
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        s, c = dr.sincos(2.0 * dr.pi * sample2.y)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = mi.Vector3f(sin_t * c, sin_t * s, cos_t)
        bs.pdf = self._pdf(si, bs.wo)
        if self.pdf_bug:                                  # the other planted bug
            bs.pdf = bs.pdf * (2.0 * dr.pi)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
        bs.sampled_component = mi.UInt32(0)
        ok = active & (bs.pdf > 0)
        # weight = eval / pdf: the lobe times the cosine, divided by the lobe
        return bs, dr.select(ok, mi.Color3f(mi.Frame3f.cos_theta(bs.wo)), 0.0)

    def eval(self, ctx, si, wo, active=True):
        return mi.Color3f(self._pdf(si, wo) * dr.maximum(mi.Frame3f.cos_theta(wo), 0.0))

    def pdf(self, ctx, si, wo, active=True):
        return self._pdf(si, wo)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def to_string(self):
        return f"PowerCosine[exponent={self.e}, bug={self.bug}]"


mi.register_bsdf("powercosine", lambda props: PowerCosine(props))


def _checks(bug: bool = False, pdf_bug: bool = False) -> list[Check]:
    plugin = {"type": "powercosine", "exponent": 4.0, "bug": bug, "pdf_bug": pdf_bug}
    tag = "".join([",bug" if bug else "", ",pdf_bug" if pdf_bug else ""])
    out = []
    for theta in (0.0, 60.0):
        wi = _direction(theta)
        name = f"powercosine(exponent=4{tag})@wi={theta:g}°"

        def run(seed, wi=wi, name=name):
            sample, pdf, domain, kw = mvm.bsdf(plugin, wi=wi)
            return mv.check_sampler(sample, pdf, domain, n_samples=200_000, seed=seed,
                                    **dict(kw, name=name))

        def run_consistency(seed, wi=wi, name="pdf_consistency:" + name):
            sample, pdf, f, kw = mvm.bsdf_weighted(plugin, wi=wi)
            return mv.check_pdf_consistency(sample, pdf, f=f, seed=seed,
                                            **dict(kw, name=name))

        out.append(Check(name, run, tags=("mitsuba", "mine")))
        out.append(Check("pdf_consistency:" + name, run_consistency, tags=("mitsuba", "mine")))
    return out


def _direction(theta_deg):
    import math

    t = math.radians(theta_deg)
    return (math.sin(t), 0.0, math.cos(t))


def suite() -> list[Check]:
    """The gate of the correct plugin."""
    return _checks(bug=False)


def planted() -> list[Check]:
    """The same checks of the plugin with its planted exponent bug: χ² fails."""
    return _checks(bug=True)


def planted_pdf() -> list[Check]:
    """The same checks of the plugin returning a pdf without its Jacobian: the
    consistency checks fail."""
    return _checks(pdf_bug=True)
