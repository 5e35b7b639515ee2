//! Export of a model's homogeneous part (sigma_a, sigma_s', eta) as material
//! snippets for pbrt-v4 and Mitsuba 3, to cross-check renders there. The
//! coefficients are the *reduced* ones with an isotropic phase function
//! (the similarity relation the dipole rests on); `unit_mm` is the length of
//! one scene unit in mm (1 for scenes in mm, 1000 for scenes in metres).

use qhm_model::DipoleParams;

fn rgb(v: [f64; 3], scale: f64) -> String {
    format!(
        "{:.6} {:.6} {:.6}",
        v[0] * scale,
        v[1] * scale,
        v[2] * scale
    )
}

/// A pbrt-v4 `MakeNamedMaterial` of type `subsurface`.
pub fn pbrt_snippet(name: &str, d: &DipoleParams, unit_mm: f64) -> String {
    format!(
        "# qhm export of {name}: homogeneous part (reduced coefficients, isotropic phase).\n\
         # sigma in mm^-1 scaled to scene units of {unit_mm} mm.\n\
         MakeNamedMaterial \"{name}\"\n    \
         \"string type\" [ \"subsurface\" ]\n    \
         \"float eta\" [ {eta} ]\n    \
         \"float g\" [ 0 ]\n    \
         \"float roughness\" [ 0 ]\n    \
         \"rgb sigma_a\" [ {sa} ]\n    \
         \"rgb sigma_s\" [ {ss} ]\n    \
         \"float scale\" [ 1 ]\n",
        eta = d.eta,
        sa = rgb(d.sigma_a(), unit_mm),
        ss = rgb(d.sigma_s_prime(), unit_mm),
    )
}

/// A Mitsuba 3 XML fragment: a smooth dielectric boundary and a homogeneous
/// interior medium (albedo a', extinction s'_t) to reference from a shape.
pub fn mitsuba_snippet(name: &str, d: &DipoleParams, unit_mm: f64) -> String {
    format!(
        "<!-- qhm export of {name}: homogeneous part (reduced coefficients, isotropic phase);\n     \
         sigma_t in mm^-1 scaled to scene units of {unit_mm} mm. Use inside a shape:\n     \
         <ref id=\"{name}-bsdf\"/> <ref name=\"interior\" id=\"{name}-medium\"/> -->\n\
         <bsdf type=\"dielectric\" id=\"{name}-bsdf\">\n    \
         <float name=\"int_ior\" value=\"{eta}\"/>\n    \
         <float name=\"ext_ior\" value=\"1.0\"/>\n\
         </bsdf>\n\
         <medium type=\"homogeneous\" id=\"{name}-medium\">\n    \
         <rgb name=\"albedo\" value=\"{albedo}\"/>\n    \
         <rgb name=\"sigma_t\" value=\"{st}\"/>\n    \
         <float name=\"scale\" value=\"1\"/>\n    \
         <phase type=\"isotropic\"/>\n\
         </medium>\n",
        eta = d.eta,
        albedo = rgb(d.alpha_prime, 1.0).replace(' ', ", "),
        st = rgb(d.sigma_t_prime, unit_mm).replace(' ', ", "),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snippets_carry_the_coefficients() {
        let d = crate::material::preset("skimmilk").unwrap();
        let p = pbrt_snippet("milk", &d, 1.0);
        assert!(
            p.contains("\"rgb sigma_a\" [ 0.001400 0.002500 0.014200 ]"),
            "{p}"
        );
        assert!(
            p.contains("\"rgb sigma_s\" [ 0.700000 1.220000 1.900000 ]"),
            "{p}"
        );
        assert!(p.contains("\"float eta\" [ 1.3 ]"));
        let m = mitsuba_snippet("milk", &d, 1000.0);
        assert!(
            m.contains("name=\"sigma_t\" value=\"701.400000, 1222.500000, 1914.200000\""),
            "{m}"
        );
        assert!(m.contains("int_ior\" value=\"1.3\""));
    }
}
