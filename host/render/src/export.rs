//! Export of a model's homogeneous part (sigma_a, sigma_s', eta) as scene
//! files for pbrt-v4 and Mitsuba 3, to cross-check renders there. The
//! coefficients are the *reduced* ones with an isotropic phase function
//! (the similarity relation the dipole rests on); `unit_mm` is the length of
//! one scene unit in mm (1 for scenes in mm, 1000 for scenes in metres).
//!
//! Both outputs load as printed: host/tests/export_interop.rs loads the
//! Mitsuba file in Mitsuba 3 and checks the pbrt file against pbrt-v4's
//! scene grammar and the parameters its creators read. The input is a
//! validated model: a' in [0, 1], s'_t > 0, finite (`DipoleParams::validate`).

use qhm_model::DipoleParams;

/// A number as the renderers will hold it: both parse to 32-bit floats, and
/// the shortest text that reads back to the same f32 loses nothing.
fn num(v: f64) -> String {
    format!("{}", v as f32)
}

fn rgb(v: [f64; 3], sep: &str) -> String {
    v.map(num).join(sep)
}

/// The name as an identifier both formats take unquoted and unescaped (XML
/// ids and comments, pbrt strings and comments): ASCII alphanumerics, `_`,
/// `-` and `.`; anything else becomes `_`.
pub fn export_name(name: &str) -> String {
    let n: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.') {
                c
            } else {
                '_'
            }
        })
        .collect();
    // "--" may not appear inside an XML comment.
    let n = n.replace("--", "-_");
    if n.is_empty() { "qhm".into() } else { n }
}

/// A pbrt-v4 include file for the world block: the homogeneous medium
/// `NAME-medium` with its dielectric boundary `NAME-interface` (volumetric
/// path tracing, the same medium as the Mitsuba export), and the tabulated
/// BSSRDF material `NAME-subsurface` (pbrt's diffusion approximation).
/// pbrt reads rgb sigma_a/sigma_s as unbounded spectra, so they stay in
/// mm^-1 and `scale` converts to scene units.
pub fn pbrt_snippet(name: &str, d: &DipoleParams, unit_mm: f64) -> String {
    let name = export_name(name);
    let (sa, ss) = (rgb(d.sigma_a(), " "), rgb(d.sigma_s_prime(), " "));
    let (eta, scale) = (num(d.eta), num(unit_mm));
    format!(
        "# qhm export of {name} for pbrt-v4: the model's homogeneous part (reduced\n\
         # coefficients, isotropic phase). sigma_a and sigma_s are in mm^-1; \"scale\"\n\
         # turns them into scene units of {unit_mm} mm. Include this file after WorldBegin\n\
         # (Include \"{name}.pbrt\"), then use either the medium in its dielectric boundary\n\
         # (volumetric path tracing, integrator \"volpath\"):\n\
         #   AttributeBegin\n\
         #     MediumInterface \"{name}-medium\" \"\"\n\
         #     NamedMaterial \"{name}-interface\"\n\
         #     Shape \"sphere\" \"float radius\" [ 10 ]\n\
         #   AttributeEnd\n\
         # or pbrt's BSSRDF material: NamedMaterial \"{name}-subsurface\".\n\
         MakeNamedMedium \"{name}-medium\"\n    \
         \"string type\" [ \"homogeneous\" ]\n    \
         \"rgb sigma_a\" [ {sa} ]\n    \
         \"rgb sigma_s\" [ {ss} ]\n    \
         \"float scale\" [ {scale} ]\n    \
         \"float g\" [ 0 ]\n\
         MakeNamedMaterial \"{name}-interface\"\n    \
         \"string type\" [ \"dielectric\" ]\n    \
         \"float eta\" [ {eta} ]\n\
         MakeNamedMaterial \"{name}-subsurface\"\n    \
         \"string type\" [ \"subsurface\" ]\n    \
         \"rgb sigma_a\" [ {sa} ]\n    \
         \"rgb sigma_s\" [ {ss} ]\n    \
         \"float scale\" [ {scale} ]\n    \
         \"float g\" [ 0 ]\n    \
         \"float eta\" [ {eta} ]\n    \
         \"float roughness\" [ 0 ]\n",
    )
}

/// A Mitsuba 3 scene file holding a smooth dielectric boundary `NAME-bsdf`
/// and a homogeneous interior medium `NAME-medium` (albedo a', extinction
/// s'_t) to `<include>` and reference from a shape. Mitsuba reads an `rgb`
/// as a reflectance in [0, 1], so sigma_t is printed divided by its largest
/// channel and that factor (times `unit_mm`) goes into `scale`.
pub fn mitsuba_snippet(name: &str, d: &DipoleParams, unit_mm: f64) -> String {
    let name = export_name(name);
    let st = d.sigma_t_prime;
    let peak = st.into_iter().fold(0.0_f64, f64::max);
    let st_rel = if peak > 0.0 {
        st.map(|s| s / peak)
    } else {
        [0.0; 3]
    };
    format!(
        "<!-- qhm export of {name} for Mitsuba 3: the model's homogeneous part (reduced\n     \
         coefficients, isotropic phase) in scene units of {unit_mm} mm; sigma_t = scale * rgb\n     \
         per scene unit (the rgb is normalised to a largest channel of 1). Include it in a\n     \
         scene and use it from a shape, with the volpath integrator:\n       \
         <include filename=\"{name}.xml\"/>\n       \
         <shape type=\"sphere\">\n           \
         <ref id=\"{name}-bsdf\"/>\n           \
         <ref name=\"interior\" id=\"{name}-medium\"/>\n       \
         </shape> -->\n\
         <scene version=\"3.0.0\">\n    \
         <bsdf type=\"dielectric\" id=\"{name}-bsdf\">\n        \
         <float name=\"int_ior\" value=\"{eta}\"/>\n        \
         <float name=\"ext_ior\" value=\"1\"/>\n    \
         </bsdf>\n    \
         <medium type=\"homogeneous\" id=\"{name}-medium\">\n        \
         <rgb name=\"albedo\" value=\"{albedo}\"/>\n        \
         <rgb name=\"sigma_t\" value=\"{st}\"/>\n        \
         <float name=\"scale\" value=\"{scale}\"/>\n        \
         <phase type=\"isotropic\"/>\n    \
         </medium>\n\
         </scene>\n",
        eta = num(d.eta),
        albedo = rgb(d.alpha_prime, ", "),
        st = rgb(st_rel, ", "),
        scale = num(peak * unit_mm),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pbrt_carries_the_coefficients_in_mm_with_the_unit_in_scale() {
        let d = crate::materials::preset("skimmilk").unwrap();
        let p = pbrt_snippet("milk", &d, 1000.0);
        for want in [
            "MakeNamedMedium \"milk-medium\"",
            "\"rgb sigma_a\" [ 0.0014 0.0025 0.0142 ]",
            "\"rgb sigma_s\" [ 0.7 1.22 1.9 ]",
            "\"float scale\" [ 1000 ]",
            "MakeNamedMaterial \"milk-interface\"",
            "\"float eta\" [ 1.3 ]",
            "MakeNamedMaterial \"milk-subsurface\"",
        ] {
            assert!(p.contains(want), "{want:?} missing from\n{p}");
        }
    }

    #[test]
    fn mitsuba_rgb_stays_in_unit_range_and_scale_restores_sigma_t() {
        let d = crate::materials::preset("skimmilk").unwrap();
        let m = mitsuba_snippet("milk", &d, 1000.0);
        // s'_t = (0.7014, 1.2225, 1.9142) mm^-1: the rgb is s'_t / 1.9142
        // and scale 1914.2 per metre.
        assert!(
            m.contains("<float name=\"scale\" value=\"1914.2\"/>"),
            "{m}"
        );
        let st_line = m.lines().find(|l| l.contains("\"sigma_t\"")).unwrap();
        let values: Vec<f64> = st_line
            .split('"')
            .nth(3)
            .unwrap()
            .split(", ")
            .map(|v| v.parse().unwrap())
            .collect();
        assert_eq!(values.len(), 3);
        assert!(values.iter().all(|v| (0.0..=1.0).contains(v)), "{st_line}");
        for (c, v) in values.iter().enumerate() {
            let back = v * 1914.2;
            let want = d.sigma_t_prime[c] * 1000.0;
            assert!(
                (back - want).abs() < 1e-6 * want,
                "channel {c}: {back} vs {want}"
            );
        }
        assert!(m.contains("int_ior\" value=\"1.3\""));
        assert!(m.trim_end().ends_with("</scene>"));
    }

    #[test]
    fn names_become_identifiers_safe_in_both_formats() {
        assert_eq!(export_name("skin1"), "skin1");
        assert_eq!(export_name("my \"odd\" <model>"), "my__odd___model_");
        assert_eq!(export_name("a--b"), "a-_b");
        assert_eq!(export_name(""), "qhm");
        let d = crate::materials::preset("apple").unwrap();
        let m = mitsuba_snippet("x&y", &d, 1.0);
        assert!(m.contains("id=\"x_y-medium\"") && !m.contains('&'));
    }
}
