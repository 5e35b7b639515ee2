//! The renderer exports load in the renderers they are for.
//!
//! - `--export-mitsuba` files load in Mitsuba 3 with the model's sigma_t,
//!   albedo and eta (tests/interop/mitsuba_load.py, run with python3). Skipped
//!   with a message when python3 cannot import mitsuba, unless
//!   QHM_REQUIRE_MITSUBA=1 (CI), where that is a failure.
//! - `--export-pbrt` files pass a checker of pbrt-v4's scene grammar and of
//!   the parameters its creators read (below; no Python), and, when QHM_PBRT
//!   names a pbrt-v4 binary, render a tiny scene in pbrt-v4 itself.

use std::path::{Path, PathBuf};
use std::process::Command;

use qhm_render::materials::preset;

const PRESETS: [&str; 5] = ["skin1", "marble", "apple", "ketchup", "wholemilk"];
/// Scene units in mm: a scene in mm and one in metres.
const UNITS_MM: [f64; 2] = [1.0, 1000.0];

/// Writes both exports of builtin:`name` for scene units of `unit_mm`.
fn export(dir: &Path, name: &str, unit_mm: f64) -> (PathBuf, PathBuf) {
    let pbrt = dir.join(format!("{name}-{unit_mm}.pbrt"));
    let xml = dir.join(format!("{name}-{unit_mm}.xml"));
    let out = Command::new(env!("CARGO_BIN_EXE_qhm"))
        .args(["render", "--model", &format!("builtin:{name}")])
        .arg("--export-pbrt")
        .arg(&pbrt)
        .arg("--export-mitsuba")
        .arg(&xml)
        .args(["--export-unit-mm", &unit_mm.to_string()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "qhm render --export-*: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (pbrt, xml)
}

// ---------------------------------------------------------------- Mitsuba 3

fn mitsuba_available() -> bool {
    Command::new("python3")
        .args(["-c", "import mitsuba"])
        .output()
        .is_ok_and(|o| o.status.success())
}

fn run_mitsuba_check(cases: &serde_json::Value, cases_file: &Path) -> (bool, String) {
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tests/interop/mitsuba_load.py"
    );
    std::fs::write(cases_file, cases.to_string()).unwrap();
    let out = Command::new("python3")
        .arg(script)
        .arg(cases_file)
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// The form Mitsuba 3 refuses: sigma_t above 1 written as an `rgb`
/// (skin1 in mm^-1, unnormalised, scale 1).
const UNNORMALISED: &str = r#"<scene version="3.0.0">
    <bsdf type="dielectric" id="skin1-bsdf">
        <float name="int_ior" value="1.3"/>
        <float name="ext_ior" value="1.0"/>
    </bsdf>
    <medium type="homogeneous" id="skin1-medium">
        <rgb name="albedo" value="0.958549, 0.838095, 0.677852"/>
        <rgb name="sigma_t" value="0.772000, 1.050000, 1.490000"/>
        <float name="scale" value="1"/>
        <phase type="isotropic"/>
    </medium>
</scene>
"#;

fn load_case(file: &Path, name: &str, unit_mm: f64, sigma_t_factor: f64) -> serde_json::Value {
    let d = preset(name).unwrap();
    serde_json::json!({
        "file": file,
        "name": name,
        "expect": "load",
        "sigma_t": d.sigma_t_prime.map(|s| s * unit_mm * sigma_t_factor),
        "albedo": d.alpha_prime,
        "eta": d.eta,
    })
}

#[test]
fn mitsuba_3_loads_the_exports_with_the_models_coefficients() {
    if !mitsuba_available() {
        let msg = "python3 cannot import mitsuba (pip install mitsuba==3.9.1)";
        if std::env::var("QHM_REQUIRE_MITSUBA").is_ok_and(|v| v == "1") {
            panic!("{msg}, and QHM_REQUIRE_MITSUBA=1");
        }
        eprintln!("skipping the Mitsuba 3 load check: {msg}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let mut cases = Vec::new();
    for name in PRESETS {
        for unit_mm in UNITS_MM {
            let (_, xml) = export(dir.path(), name, unit_mm);
            cases.push(load_case(&xml, name, unit_mm, 1.0));
        }
    }
    let old = dir.path().join("unnormalised.xml");
    std::fs::write(&old, UNNORMALISED).unwrap();
    cases.push(serde_json::json!({ "file": old, "expect": "refuse" }));
    let (ok, text) = run_mitsuba_check(
        &serde_json::Value::Array(cases),
        &dir.path().join("cases.json"),
    );
    assert!(ok, "{text}");
    assert!(text.contains("11 passed, 0 failed"), "{text}");

    // The check itself can fail: a sigma_t 0.1 % off is caught.
    let xml = dir.path().join("skin1-1000.xml");
    let wrong = serde_json::json!([load_case(&xml, "skin1", 1000.0, 1.001)]);
    let (ok, text) = run_mitsuba_check(&wrong, &dir.path().join("wrong.json"));
    assert!(
        !ok && text.contains("FAIL") && text.contains("sigma_t"),
        "{text}"
    );
}

// ------------------------------------------------------------------ pbrt-v4

#[derive(Debug, PartialEq)]
enum Tok {
    Bare(String),
    Quoted(String),
    Open,
    Close,
}

/// pbrt-v4's tokenizer (src/pbrt/parser.cpp, Tokenizer::Next): whitespace
/// separates, `"..."` is a string (no newline inside, backslash escapes), `[`
/// and `]` stand alone, `#` comments to the end of the line, anything else
/// runs to whitespace, a quote or a bracket.
fn tokenize(text: &str) -> Result<Vec<(usize, Tok)>, String> {
    let mut out = Vec::new();
    let mut chars = text.chars().peekable();
    let mut line = 1;
    while let Some(c) = chars.next() {
        match c {
            '\n' => line += 1,
            ' ' | '\t' | '\r' => {}
            '[' => out.push((line, Tok::Open)),
            ']' => out.push((line, Tok::Close)),
            '#' => {
                while chars.peek().is_some_and(|&c| c != '\n' && c != '\r') {
                    chars.next();
                }
            }
            '"' => {
                let mut s = String::new();
                loop {
                    match chars.next() {
                        None | Some('\n') => {
                            return Err(format!("line {line}: unterminated string"));
                        }
                        Some('"') => break,
                        Some('\\') => s.push(match chars.next() {
                            Some('b') => '\u{8}',
                            Some('f') => '\u{c}',
                            Some('n') => '\n',
                            Some('r') => '\r',
                            Some('t') => '\t',
                            Some(c @ ('\\' | '\'' | '"')) => c,
                            other => {
                                return Err(format!("line {line}: bad escape {other:?}"));
                            }
                        }),
                        Some(c) => s.push(c),
                    }
                }
                out.push((line, Tok::Quoted(s)));
            }
            c => {
                let mut s = String::from(c);
                while let Some(&c) = chars.peek() {
                    if matches!(c, ' ' | '\n' | '\t' | '\r' | '"' | '[' | ']') {
                        break;
                    }
                    s.push(c);
                    chars.next();
                }
                out.push((line, Tok::Bare(s)));
            }
        }
    }
    Ok(out)
}

#[derive(Debug, Clone, PartialEq)]
enum Value {
    Num(f64),
    Str(String),
    Bool(bool),
}

#[derive(Debug)]
struct Param {
    ty: String,
    name: String,
    values: Vec<Value>,
}

#[derive(Debug)]
struct Directive {
    line: usize,
    keyword: String,
    name: String,
    params: Vec<Param>,
}

impl Directive {
    fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }
    fn type_string(&self) -> Option<&str> {
        match self.param("type").map(|p| (p.ty.as_str(), &p.values[..])) {
            Some(("string", [Value::Str(s)])) => Some(s),
            _ => None,
        }
    }
    fn nums(&self, name: &str) -> Vec<f64> {
        self.param(name)
            .map(|p| {
                p.values
                    .iter()
                    .filter_map(|v| match v {
                        Value::Num(x) => Some(*x),
                        _ => None,
                    })
                    .collect()
            })
            .unwrap_or_default()
    }
}

/// Parses an include file for pbrt-v4's world block, as the parser
/// (parser.cpp: parse, parseParameters) and the parameter dictionary
/// (paramdict.cpp: checkParameterTypes) read it. Only the directives qhm
/// exports are accepted: MakeNamedMedium and MakeNamedMaterial.
fn parse_pbrt(text: &str) -> Result<Vec<Directive>, String> {
    let toks = tokenize(text)?;
    let mut it = toks.into_iter().peekable();
    let mut out = Vec::new();
    while let Some((line, tok)) = it.next() {
        let Tok::Bare(keyword) = tok else {
            return Err(format!("line {line}: expected a directive, found {tok:?}"));
        };
        if !matches!(keyword.as_str(), "MakeNamedMedium" | "MakeNamedMaterial") {
            return Err(format!(
                "line {line}: directive {keyword} is not expected here"
            ));
        }
        let Some((_, Tok::Quoted(name))) = it.next() else {
            return Err(format!("line {line}: {keyword} needs a quoted name"));
        };
        let mut params = Vec::new();
        while let Some((pline, Tok::Quoted(_))) = it.peek() {
            let pline = *pline;
            let Some((_, Tok::Quoted(decl))) = it.next() else {
                unreachable!()
            };
            let words: Vec<&str> = decl.split([' ', '\t']).filter(|w| !w.is_empty()).collect();
            let [ty, pname] = words[..] else {
                return Err(format!(
                    "line {pline}: parameter {decl:?} is not \"type name\""
                ));
            };
            let mut raw = Vec::new();
            match it.next() {
                Some((_, Tok::Open)) => loop {
                    match it.next() {
                        Some((_, Tok::Close)) => break,
                        Some((_, Tok::Open)) | None => {
                            return Err(format!("line {pline}: unclosed [ for {pname}"));
                        }
                        Some((_, t)) => raw.push(t),
                    }
                },
                Some((_, t @ (Tok::Bare(_) | Tok::Quoted(_)))) => raw.push(t),
                _ => return Err(format!("line {pline}: no value for {pname}")),
            }
            let mut values = Vec::new();
            for t in raw {
                values.push(match t {
                    Tok::Quoted(s) => Value::Str(s),
                    Tok::Bare(b) if b == "true" => Value::Bool(true),
                    Tok::Bare(b) if b == "false" => Value::Bool(false),
                    Tok::Bare(b) => match b.parse::<f64>() {
                        Ok(x) if x.is_finite() => Value::Num(x),
                        _ => return Err(format!("line {pline}: {b:?}: expected a number")),
                    },
                    _ => unreachable!(),
                });
            }
            if values
                .windows(2)
                .any(|w| std::mem::discriminant(&w[0]) != std::mem::discriminant(&w[1]))
            {
                return Err(format!("line {pline}: {pname}: mixed value kinds"));
            }
            let all = |f: fn(&Value) -> bool| !values.is_empty() && values.iter().all(f);
            let nums = all(|v| matches!(v, Value::Num(_)));
            let strs = all(|v| matches!(v, Value::Str(_)));
            let kinds_ok = match ty {
                "bool" => all(|v| matches!(v, Value::Bool(_))),
                "integer" => all(|v| matches!(v, Value::Num(x) if x.fract() == 0.0)),
                "float" | "point2" | "vector2" | "point3" | "vector3" | "normal" | "rgb"
                | "blackbody" => nums,
                "string" | "texture" => strs,
                "spectrum" => nums || strs,
                _ => return Err(format!("line {pline}: \"{ty}\": unknown parameter type")),
            };
            if !kinds_ok {
                return Err(format!(
                    "line {pline}: {ty} {pname}: values of the wrong kind"
                ));
            }
            if params.iter().any(|p: &Param| p.name == pname) {
                return Err(format!("line {pline}: {pname} given twice"));
            }
            params.push(Param {
                ty: ty.into(),
                name: pname.into(),
                values,
            });
        }
        out.push(Directive {
            line,
            keyword,
            name,
            params,
        });
    }
    Ok(out)
}

/// Which types a parameter may have for what reads it, by name.
type Accepts = &'static [(&'static str, &'static [&'static str])];

const SPECTRUM: &[&str] = &["rgb", "spectrum", "blackbody"];
const SPECTRUM_TEX: &[&str] = &["rgb", "spectrum", "blackbody", "texture"];
const FLOAT: &[&str] = &["float"];
const FLOAT_TEX: &[&str] = &["float", "texture"];
const MATERIAL_COMMON: Accepts = &[
    ("type", &["string"]),
    ("normalmap", &["string"]), // read by scene.cpp for every material
    ("displacement", FLOAT_TEX),
];

/// The parameters pbrt-v4 reads, from src/pbrt/media.cpp
/// (HomogeneousMedium::Create) and src/pbrt/materials.cpp
/// (DielectricMaterial::Create, SubsurfaceMaterial::Create, the
/// "interface" case of Material::Create); pbrt stops on any other
/// ("unused parameter").
fn accepted(keyword: &str, ty: &str) -> Option<Vec<(&'static str, &'static [&'static str])>> {
    let roughness: Accepts = &[
        ("roughness", FLOAT_TEX),
        ("uroughness", FLOAT_TEX),
        ("vroughness", FLOAT_TEX),
        ("remaproughness", &["bool"]),
    ];
    let own: Accepts = match (keyword, ty) {
        ("MakeNamedMedium", "homogeneous") => &[
            ("type", &["string"]),
            ("preset", &["string"]),
            ("sigma_a", SPECTRUM),
            ("sigma_s", SPECTRUM),
            ("scale", FLOAT),
            ("g", FLOAT),
            ("Le", SPECTRUM),
            ("Lescale", FLOAT),
        ],
        ("MakeNamedMaterial", "dielectric") => {
            &[("eta", &["float", "rgb", "spectrum", "blackbody"])]
        }
        ("MakeNamedMaterial", "subsurface") => &[
            ("g", FLOAT),
            ("name", &["string"]),
            ("sigma_a", SPECTRUM_TEX),
            ("sigma_s", SPECTRUM_TEX),
            ("reflectance", SPECTRUM_TEX),
            ("mfp", SPECTRUM_TEX),
            ("scale", FLOAT),
            ("eta", FLOAT),
        ],
        ("MakeNamedMaterial", "interface") => &[],
        _ => return None,
    };
    let mut all: Vec<_> = own.to_vec();
    if keyword == "MakeNamedMaterial" {
        all.extend_from_slice(MATERIAL_COMMON);
        if ty != "interface" {
            all.extend_from_slice(roughness);
        }
    }
    Some(all)
}

/// Checks what pbrt-v4 checks when it creates the objects: a known type,
/// only parameters it reads, each with a type it reads and the number of
/// values that lookup takes (one float, three rgb components, not negative).
fn check_pbrt(text: &str) -> Result<Vec<Directive>, String> {
    let doc = parse_pbrt(text)?;
    let mut names = std::collections::HashSet::new();
    for d in &doc {
        let at = format!("line {}: {} {:?}", d.line, d.keyword, d.name);
        if !names.insert((d.keyword.clone(), d.name.clone())) {
            return Err(format!("{at}: redefined"));
        }
        let ty = d
            .type_string()
            .ok_or(format!("{at}: needs one \"string type\""))?;
        let accepts = accepted(&d.keyword, ty).ok_or(format!("{at}: type {ty:?} unknown here"))?;
        for p in &d.params {
            let Some((_, types)) = accepts.iter().find(|(n, _)| *n == p.name) else {
                return Err(format!("{at}: {:?}: unused parameter", p.name));
            };
            if !types.contains(&p.ty.as_str()) {
                return Err(format!(
                    "{at}: {} {} is not read (types {types:?})",
                    p.ty, p.name
                ));
            }
            let count = match p.ty.as_str() {
                "rgb" => 3,
                "blackbody" | "float" | "string" | "texture" | "bool" | "integer" => 1,
                _ => p.values.len(),
            };
            if p.values.len() != count {
                return Err(format!("{at}: {} wants {count} value(s)", p.name));
            }
            if p.ty == "rgb" && d.nums(&p.name).iter().any(|&x| x < 0.0) {
                return Err(format!("{at}: rgb {} has a negative component", p.name));
            }
        }
        if ty == "subsurface" && (d.param("sigma_a").is_some() != d.param("sigma_s").is_some()) {
            return Err(format!("{at}: sigma_a and sigma_s go together"));
        }
    }
    Ok(doc)
}

fn close(got: &[f64], want: &[f64]) -> bool {
    got.len() == want.len()
        && got
            .iter()
            .zip(want)
            .all(|(g, w)| (g - w).abs() <= 1e-6 * w.abs().max(1e-30))
}

#[test]
fn pbrt_exports_follow_pbrt_v4_grammar_with_the_models_coefficients() {
    let dir = tempfile::tempdir().unwrap();
    for name in PRESETS {
        for unit_mm in UNITS_MM {
            let (pbrt, _) = export(dir.path(), name, unit_mm);
            let text = std::fs::read_to_string(&pbrt).unwrap();
            let doc = check_pbrt(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
            let d = preset(name).unwrap();
            let find = |kw: &str, n: String| {
                doc.iter()
                    .find(|x| x.keyword == kw && x.name == n)
                    .unwrap_or_else(|| panic!("no {kw} {n:?} in\n{text}"))
            };
            let per_unit = |v: [f64; 3]| v.map(|x| x * unit_mm);
            for obj in [
                find("MakeNamedMedium", format!("{name}-medium")),
                find("MakeNamedMaterial", format!("{name}-subsurface")),
            ] {
                let scale = obj.nums("scale")[0];
                let sa: Vec<f64> = obj.nums("sigma_a").iter().map(|x| x * scale).collect();
                let ss: Vec<f64> = obj.nums("sigma_s").iter().map(|x| x * scale).collect();
                assert!(
                    close(&sa, &per_unit(d.sigma_a())),
                    "{name} {unit_mm}: {sa:?}"
                );
                assert!(
                    close(&ss, &per_unit(d.sigma_s_prime())),
                    "{name} {unit_mm}: {ss:?}"
                );
                assert_eq!(obj.nums("g"), [0.0]);
            }
            let interface = find("MakeNamedMaterial", format!("{name}-interface"));
            assert_eq!(interface.type_string(), Some("dielectric"));
            assert!(close(&interface.nums("eta"), &[d.eta]));
        }
    }
}

#[test]
fn the_pbrt_checker_rejects_what_pbrt_v4_rejects() {
    let good = "MakeNamedMedium \"m\" \"string type\" \"homogeneous\" \"rgb sigma_a\" [ 1 2 3 ]";
    assert!(check_pbrt(good).is_ok());
    for (bad, why) in [
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"rgb sigma_a\" [ 1 2 ]",
            "3 value",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"float sigma\" [ 1 ]",
            "unused",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"color sigma_a\" [ 1 1 1 ]",
            "unknown parameter type",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"rgb scale\" [ 1 1 1 ]",
            "not read",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"float g\" [ 0 1 ]",
            "1 value",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"rgb sigma_s\" [ 1 -1 1 ]",
            "negative",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"float g\" [ x ]",
            "number",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" \"float g\" [ 0 ]",
            "unclosed",
        ),
        (
            "MakeNamedMedium \"m\" \"string type\" [ \"homogeneous\" ] \"float g\" [ 0 \"x\" ]",
            "mixed",
        ),
        (
            "MakeNamedMedium \"m\" \"rgb sigma_a\" [ 1 1 1 ]",
            "string type",
        ),
        (
            "MakeNamedMaterial \"m\" \"string type\" [ \"dielectric\" ] \"float eta\" [ 1.3 ]\n\
          MakeNamedMaterial \"m\" \"string type\" [ \"dielectric\" ]",
            "redefined",
        ),
        (
            "MakeNamedMaterial \"m\" \"string type\" [ \"subsurface\" ] \"rgb sigma_a\" [ 1 1 1 ]",
            "together",
        ),
        (
            "MakeNamedMaterial \"m\" \"string type\" [ \"subsurface\" ] \"rgb eta\" [ 1 1 1 ]",
            "not read",
        ),
        (
            "MakeNamedMaterial \"m\" \"string type\" [ \"dielectric\" ] \"float eta [ 1.3 ]",
            "unterminated",
        ),
        (
            "MakeNamedMaterial m \"string type\" [ \"dielectric\" ]",
            "quoted name",
        ),
        ("Material \"dielectric\"", "not expected"),
        (
            "MakeNamedMaterial \"m\" \"string type\" [ \"plastic\" ]",
            "unknown here",
        ),
    ] {
        match check_pbrt(bad) {
            Ok(_) => panic!("accepted: {bad}"),
            Err(e) => assert!(e.contains(why), "{bad}\n  gave {e:?}, wanted {why:?}"),
        }
    }
}

#[test]
fn pbrt_v4_renders_the_exports_when_given_a_binary() {
    let Some(pbrt) = std::env::var_os("QHM_PBRT") else {
        eprintln!("skipping the pbrt-v4 render: set QHM_PBRT to a pbrt-v4 binary");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for (name, unit_mm) in [("skin1", 1.0), ("ketchup", 1000.0)] {
        let (include, _) = export(dir.path(), name, unit_mm);
        // A 20-unit sphere with the medium, a small one with the BSSRDF.
        let scene = format!(
            "LookAt 0 0 80  0 0 0  0 1 0\n\
             Camera \"perspective\" \"float fov\" [ 40 ]\n\
             Film \"rgb\" \"integer xresolution\" [ 16 ] \"integer yresolution\" [ 16 ]\n    \
             \"string filename\" [ \"{name}.exr\" ]\n\
             Sampler \"independent\" \"integer pixelsamples\" [ 4 ]\n\
             Integrator \"volpath\" \"integer maxdepth\" [ 16 ]\n\
             WorldBegin\n\
             LightSource \"infinite\" \"rgb L\" [ 1 1 1 ]\n\
             Include \"{}\"\n\
             AttributeBegin\n  MediumInterface \"{name}-medium\" \"\"\n  \
             NamedMaterial \"{name}-interface\"\n  Shape \"sphere\" \"float radius\" [ 20 ]\n\
             AttributeEnd\n\
             AttributeBegin\n  Translate 25 0 0\n  NamedMaterial \"{name}-subsurface\"\n  \
             Shape \"sphere\" \"float radius\" [ 4 ]\nAttributeEnd\n",
            include.display()
        );
        let scene_file = dir.path().join(format!("{name}-scene.pbrt"));
        std::fs::write(&scene_file, scene).unwrap();
        let out = Command::new(&pbrt)
            .args(["--nthreads", "1", "--quiet"])
            .arg(&scene_file)
            .current_dir(dir.path())
            .output()
            .unwrap();
        let text = format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(out.status.success() && !text.contains("Error"), "{text}");
        assert!(dir.path().join(format!("{name}.exr")).exists(), "{text}");
    }
}
