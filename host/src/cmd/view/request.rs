//! What the page asks for: the view state as JSON (mesh, mode, env map,
//! size, orbit camera, directional light, exposure, refinement level),
//! checked into a [`View`], and the scene TOML that `qhm render --scene`
//! reads for it. The viewer renders through that same TOML, so a saved
//! scene reproduces the image exactly.

use std::fmt::Write;

use glam::Vec3;
use qhm_render::{Mode, RenderSettings};
use serde::Deserialize;

/// Smallest and largest image side the viewer renders.
pub const SIZE_MIN: u32 = 16;
pub const SIZE_MAX: u32 = 1024;
/// Environment maps the page offers: the render's built-ins (at half
/// strength, as `qhm render`'s default scene) or none.
pub const ENV_NAMES: [&str; 3] = ["studio", "sky", "none"];
pub const ENV_SCALE: f32 = 0.5;
/// The camera's vertical field of view, as `qhm render`'s default framing.
pub const FOV_DEG: f32 = 30.0;

/// The request body of `/api/render` and `/api/save`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewRequest {
    pub mesh: String,
    #[serde(default = "default_mode")]
    pub mode: String,
    #[serde(default = "default_env")]
    pub env: String,
    #[serde(default = "default_size")]
    pub width: u32,
    #[serde(default = "default_size")]
    pub height: u32,
    #[serde(default)]
    pub camera: Orbit,
    #[serde(default)]
    pub light: LightDir,
    /// PNG exposure multiplier (the image itself is linear).
    #[serde(default = "default_exposure")]
    pub exposure: f32,
    /// Refinement level, 0 (preview) .. LEVELS - 1 (`qhm render` quality).
    #[serde(default)]
    pub level: usize,
}

/// The camera on a sphere around the object's bounding-box centre.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Orbit {
    /// About +z from +x, degrees.
    pub azimuth_deg: f32,
    /// Above the horizontal plane, degrees, within +-89.
    pub elevation_deg: f32,
    /// Distance as a multiple of the default framing distance.
    pub distance: f32,
}

/// The one directional light, by the direction towards it.
#[derive(Clone, Copy, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightDir {
    pub azimuth_deg: f32,
    /// -90 (from straight below) .. 90 (from above).
    pub elevation_deg: f32,
    /// Irradiance on a surface facing the light (grey).
    #[serde(default = "default_irradiance")]
    pub irradiance: f32,
}

impl Default for Orbit {
    /// `qhm render`'s default framing direction (0.35, -1, 0.55).
    fn default() -> Orbit {
        Orbit {
            azimuth_deg: -70.7,
            elevation_deg: 27.4,
            distance: 1.0,
        }
    }
}

impl Default for LightDir {
    /// `qhm render`'s default key light, towards (-0.5, -0.8, 1).
    fn default() -> LightDir {
        LightDir {
            azimuth_deg: -122.0,
            elevation_deg: 46.0,
            irradiance: default_irradiance(),
        }
    }
}

fn default_mode() -> String {
    "full".into()
}
fn default_env() -> String {
    "studio".into()
}
fn default_size() -> u32 {
    256
}
fn default_exposure() -> f32 {
    1.0
}
fn default_irradiance() -> f32 {
    2.0
}

/// A checked request.
#[derive(Clone, Debug)]
pub struct View {
    pub mesh: String,
    pub mode: Mode,
    pub mode_name: String,
    pub env: String,
    pub width: u32,
    pub height: u32,
    pub camera: Orbit,
    pub light: LightDir,
    pub exposure: f32,
    pub level: usize,
}

/// Parses and checks a request body; the error is the message for a 400.
pub fn parse_view(body: &[u8], meshes: &[String], levels: usize) -> Result<View, String> {
    let r: ViewRequest =
        serde_json::from_slice(body).map_err(|e| format!("malformed request JSON: {e}"))?;
    if !meshes.contains(&r.mesh) {
        return Err(format!(
            "unknown mesh {:?} (known: {})",
            r.mesh,
            meshes.join(", ")
        ));
    }
    let mode: Mode = r.mode.parse().map_err(|e| format!("{e}"))?;
    if !ENV_NAMES.contains(&r.env.as_str()) {
        return Err(format!(
            "unknown env {:?} (known: {})",
            r.env,
            ENV_NAMES.join(", ")
        ));
    }
    for (what, v) in [("width", r.width), ("height", r.height)] {
        if !(SIZE_MIN..=SIZE_MAX).contains(&v) {
            return Err(format!("{what} {v} out of range {SIZE_MIN}..={SIZE_MAX}"));
        }
    }
    let c = r.camera;
    let l = r.light;
    let checks = [
        ("camera.azimuth_deg", c.azimuth_deg, f32::MIN, f32::MAX),
        ("camera.elevation_deg", c.elevation_deg, -89.0, 89.0),
        ("camera.distance", c.distance, 0.1, 10.0),
        ("light.azimuth_deg", l.azimuth_deg, f32::MIN, f32::MAX),
        ("light.elevation_deg", l.elevation_deg, -90.0, 90.0),
        ("light.irradiance", l.irradiance, 0.0, 1000.0),
        ("exposure", r.exposure, 1e-4, 1e4),
    ];
    for (what, v, lo, hi) in checks {
        if !(v.is_finite() && v >= lo && v <= hi) {
            return Err(format!("{what} {v} out of range [{lo}, {hi}]"));
        }
    }
    if r.level >= levels {
        return Err(format!("level {} out of range 0..{levels}", r.level));
    }
    Ok(View {
        mode_name: Mode::NAMES
            .iter()
            .find(|n| n.parse::<Mode>().ok() == Some(mode))
            .map_or(r.mode.clone(), |n| n.to_string()),
        mesh: r.mesh,
        mode,
        env: r.env,
        width: r.width,
        height: r.height,
        camera: c,
        light: l,
        exposure: r.exposure,
        level: r.level,
    })
}

/// The unit vector at azimuth/elevation (degrees), z up.
pub fn direction(azimuth_deg: f32, elevation_deg: f32) -> Vec3 {
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    Vec3::new(el.cos() * az.cos(), el.cos() * az.sin(), el.sin())
}

/// Where the camera looks and how far back it stands by default.
#[derive(Clone, Copy, Debug)]
pub struct Framing {
    pub center: Vec3,
    pub distance: f32,
}

impl Framing {
    /// As `qhm render`'s default camera: the bounding sphere fills the
    /// field of view with 5 % to spare.
    pub fn of_bounds(lo: Vec3, hi: Vec3) -> Framing {
        let r = (hi - lo).length() * 0.5;
        Framing {
            center: (lo + hi) * 0.5,
            distance: r / (FOV_DEG.to_radians() * 0.5).sin() * 1.05,
        }
    }
}

/// The scene TOML of a view, in three parts: what the surface samples'
/// irradiance depends on (lights, env map, mode), the camera, and the
/// `[render]` table at `qhm render`'s default quality.
pub struct SceneToml {
    pub lighting: String,
    pub camera: String,
    pub object: String,
    pub render: String,
}

impl SceneToml {
    pub fn new(view: &View, framing: Framing, object_scale: Option<f32>) -> SceneToml {
        let c = view.camera;
        let eye = framing.center
            + direction(c.azimuth_deg, c.elevation_deg) * framing.distance * c.distance;
        let mut camera = String::from("[camera]\n");
        let _ = writeln!(camera, "eye = {}", vec(eye));
        let _ = writeln!(camera, "target = {}", vec(framing.center));
        let _ = writeln!(camera, "up = [0, 0, 1]\nfov_deg = {FOV_DEG}");

        let l = view.light;
        let mut lighting = String::from("[[lights]]\nkind = \"directional\"\n");
        let _ = writeln!(
            lighting,
            "direction = {}",
            vec(direction(l.azimuth_deg, l.elevation_deg))
        );
        let _ = writeln!(lighting, "irradiance = {}", vec(Vec3::splat(l.irradiance)));
        let _ = write!(lighting, "\n[env]\nbuiltin = \"{}\"\n", view.env);
        if view.env != "none" {
            let _ = writeln!(lighting, "scale = {ENV_SCALE}");
        }

        let object = match object_scale {
            Some(s) => format!("[object]\nscale = {s}\n"),
            None => String::new(),
        };

        let d = RenderSettings::default();
        let mut render = String::from("[render]\n");
        let _ = writeln!(render, "mode = \"{}\"", view.mode_name);
        let _ = writeln!(render, "width = {}\nheight = {}", view.width, view.height);
        let _ = writeln!(render, "spp = {}", d.spp);
        let _ = writeln!(render, "surface_samples = {}", d.surface_samples);
        let _ = writeln!(render, "env_samples = {}", d.env_samples);
        let _ = writeln!(render, "light_samples = {}", d.light_samples);
        let _ = writeln!(render, "seed = {}", d.seed);
        SceneToml {
            lighting,
            camera,
            object,
            render,
        }
    }

    /// The whole file.
    pub fn text(&self) -> String {
        let mut t = format!("{}\n{}\n", self.camera, self.lighting);
        if !self.object.is_empty() {
            t.push_str(&self.object);
            t.push('\n');
        }
        t.push_str(&self.render);
        t
    }
}

/// A TOML array; Rust prints the shortest decimal that reads back as the
/// same f32, so the file reproduces the viewer's camera bit for bit.
fn vec(v: Vec3) -> String {
    format!("[{}, {}, {}]", v.x, v.y, v.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meshes() -> Vec<String> {
        vec!["sphere".into(), "slab".into()]
    }

    #[test]
    fn defaults_fill_a_minimal_request() {
        let v = parse_view(br#"{"mesh": "sphere"}"#, &meshes(), 4).unwrap();
        assert_eq!(
            (v.width, v.height, v.mode, v.level),
            (256, 256, Mode::Full, 0)
        );
        let d = direction(v.camera.azimuth_deg, v.camera.elevation_deg);
        let want = Vec3::new(0.35, -1.0, 0.55).normalize();
        assert!(d.distance(want) < 2e-3, "{d}");
    }

    #[test]
    fn bad_requests_say_what_is_wrong() {
        let cases: [(&[u8], &str); 9] = [
            (b"{", "malformed"),
            (br#"{"mesh": "cube"}"#, "unknown mesh"),
            (br#"{"mesh": "sphere", "mode": "bogus"}"#, "bogus"),
            (br#"{"mesh": "sphere", "env": "moon"}"#, "unknown env"),
            (br#"{"mesh": "sphere", "width": 8}"#, "width 8"),
            (br#"{"mesh": "sphere", "height": 5000}"#, "height 5000"),
            (br#"{"mesh": "sphere", "level": 9}"#, "level 9"),
            (
                br#"{"mesh": "sphere", "camera": {"azimuth_deg": 0, "elevation_deg": 95, "distance": 1}}"#,
                "camera.elevation_deg",
            ),
            (br#"{"mesh": "sphere", "colour": 1}"#, "unknown field"),
        ];
        for (body, needle) in cases {
            let e = parse_view(body, &meshes(), 4).unwrap_err();
            assert!(e.contains(needle), "{}: {e}", String::from_utf8_lossy(body));
        }
    }

    #[test]
    fn scene_toml_reads_back() {
        let v = parse_view(br#"{"mesh": "sphere", "mode": "btf"}"#, &meshes(), 4).unwrap();
        let f = Framing::of_bounds(Vec3::splat(-20.0), Vec3::splat(20.0));
        let t = SceneToml::new(&v, f, Some(2.0)).text();
        let file = qhm_render::SceneFile::parse(&t, None).unwrap();
        let mut s = RenderSettings::default();
        file.apply_settings(&mut s).unwrap();
        assert_eq!((s.mode, s.width), (Mode::LrfOnly, 256));
        assert!(t.contains("mode = \"lrf-only\""), "{t}");
        assert_eq!(file.object().unwrap().0, 2.0);
    }
}
