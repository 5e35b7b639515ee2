//! Scenes: the mesh with its BVH, a camera, lights and an optional
//! environment map; built-in scenes; and the scene TOML (`--scene`), whose
//! every table is optional and overrides the defaults:
//!
//! Omitted keys keep their defaults, in a table too: `[camera]` with
//! only `fov_deg` frames the object from the default direction.
//!
//! ```toml
//! [camera]                      # mm, z up
//! eye = [0, -200, 120]          # default: framing the object from the front left
//! target = [0, 0, 20]           # default: the object's bounding-box centre
//! up = [0, 0, 1]
//! fov_deg = 30
//!
//! [[lights]]                    # any number
//! kind = "directional"          # or "point"
//! direction = [1, -1, 2]        # towards the light (directional)
//! irradiance = [3, 3, 3]        # on a surface facing the light
//! # position = [x, y, z]; intensity = [r, g, b]   (point, per steradian)
//!
//! [env]                         # optional
//! builtin = "sky"               # "sky" | "studio", or file = "map.exr"
//! scale = 1.0
//! rotate_deg = 0
//! sun = [1, -1, 1]              # sky only
//! visible = true                # seen as background
//!
//! [object]
//! scale = 1.0                   # mm per mesh-file (or built-in) unit; the object
//!                               # must come out 0.001 mm to 1e7 mm across
//! uv_scale_mm = 40              # mm per file UV unit (default: bbox diagonal);
//!                               # mesh files only
//!
//! [render]                      # see RenderSettings
//! mode = "full"                 # full | lrf-only | lrf-dipole | dipole-only
//! width = 512
//! height = 512
//! spp = 4
//! surface_samples = 40000
//! epsilon = 0.1
//! env_samples = 64
//! light_samples = 16
//! local_radius_mm = 0.0
//! near_field = 6.0              # irradiance interpolation radius, in sample radii (0 = off)
//! geometry = true               # the dipole's exit-plane factor on curved/thin objects
//! curvature = true              # its curvature gain on smooth convex and concave parts
//! indirect_rays = 8             # rays per sample for light between parts (0 = off)
//! seed = 1
//! ```

use std::f32::consts::PI;
use std::path::Path;

use glam::Vec3;
use serde::Deserialize;

use crate::builtin::builtin_mesh;
use crate::bvh::Bvh;
use crate::camera::Camera;
use crate::error::RenderError;
use crate::light::{EnvMap, Light};
use crate::mesh::Mesh;
use crate::settings::{Mode, RenderSettings};

/// Everything that is rendered.
pub struct Scene {
    pub mesh: Mesh,
    pub bvh: Bvh,
    /// The mesh's [`Mesh::outside`], found with the BVH when the scene is
    /// made: the side light can reach its surface from.
    pub outside: Option<f32>,
    pub camera: Camera,
    pub lights: Vec<Light>,
    pub env: Option<EnvMap>,
    /// Show the environment behind the object (else black).
    pub env_visible: bool,
    /// Ray offset to leave a surface, mm (scaled to the object size).
    pub eps: f32,
}

impl Scene {
    /// A scene around `mesh` with a camera framing it and no lights.
    pub fn new(mesh: Mesh) -> Scene {
        let (lo, hi) = mesh.bounds();
        let diag = (hi - lo).length();
        let camera = frame_camera(lo, hi);
        let bvh = Bvh::new(&mesh);
        let outside = mesh.outside();
        Scene {
            mesh,
            bvh,
            outside,
            camera,
            lights: Vec::new(),
            env: None,
            env_visible: true,
            eps: diag * 2e-5,
        }
    }

    /// A built-in object with a default camera and a studio environment plus
    /// a key light.
    pub fn builtin(name: &str) -> Result<Scene, RenderError> {
        Ok(Scene::lit(builtin_mesh(name)?))
    }

    /// A scene around `mesh` with the default lighting: a studio
    /// environment (scale 0.5) and a key light from the front left.
    pub fn lit(mesh: Mesh) -> Scene {
        let mut s = Scene::new(mesh);
        s.env = Some(EnvMap::studio(0.5));
        s.lights.push(Light::Directional {
            to_light: Vec3::new(-0.5, -0.8, 1.0).normalize(),
            irradiance: Vec3::splat(2.0),
        });
        s
    }
}

/// A camera looking at the box from the front-left and above.
pub fn frame_camera(lo: Vec3, hi: Vec3) -> Camera {
    frame_camera_fov(lo, hi, DEFAULT_FOV_DEG.to_radians())
}

/// Vertical field of view of the default camera, degrees.
pub const DEFAULT_FOV_DEG: f32 = 30.0;

/// [`frame_camera`] with a vertical field of view of `fov` radians: the
/// eye as far as the box's bounding sphere needs to fill the view.
pub fn frame_camera_fov(lo: Vec3, hi: Vec3, fov: f32) -> Camera {
    let c = (lo + hi) * 0.5;
    let r = (hi - lo).length() * 0.5;
    let dist = r / (fov * 0.5).sin() * 1.05;
    let dir = Vec3::new(0.35, -1.0, 0.55).normalize();
    Camera::look_at(c + dir * dist, c, fov)
}

/// The scene TOML.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    pub camera: Option<CameraToml>,
    #[serde(default)]
    pub lights: Vec<LightToml>,
    pub env: Option<EnvToml>,
    pub object: Option<ObjectToml>,
    pub render: Option<RenderToml>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraToml {
    pub eye: Option<[f32; 3]>,
    pub target: Option<[f32; 3]>,
    pub up: Option<[f32; 3]>,
    pub fov_deg: Option<f32>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LightToml {
    pub kind: String,
    pub direction: Option<[f32; 3]>,
    pub irradiance: Option<[f32; 3]>,
    pub position: Option<[f32; 3]>,
    pub intensity: Option<[f32; 3]>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvToml {
    pub builtin: Option<String>,
    pub file: Option<String>,
    pub scale: Option<f32>,
    pub rotate_deg: Option<f32>,
    pub sun: Option<[f32; 3]>,
    pub visible: Option<bool>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectToml {
    pub scale: Option<f32>,
    pub uv_scale_mm: Option<f32>,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderToml {
    pub mode: Option<String>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub spp: Option<u32>,
    pub surface_samples: Option<usize>,
    pub epsilon: Option<f32>,
    pub env_samples: Option<usize>,
    pub light_samples: Option<usize>,
    pub local_radius_mm: Option<f32>,
    pub near_field: Option<f32>,
    pub geometry: Option<bool>,
    pub curvature: Option<bool>,
    pub indirect_rays: Option<usize>,
    pub seed: Option<u64>,
    pub synthesis: Option<bool>,
}

fn vec3(v: [f32; 3], what: &str) -> Result<Vec3, RenderError> {
    let v = Vec3::from(v);
    if !v.is_finite() {
        return Err(RenderError::Scene(format!("{what} is not finite")));
    }
    Ok(v)
}

fn unit(v: [f32; 3], what: &str) -> Result<Vec3, RenderError> {
    vec3(v, what)?
        .try_normalize()
        .ok_or_else(|| RenderError::Scene(format!("{what} is the zero vector")))
}

fn colour(v: [f32; 3], what: &str) -> Result<Vec3, RenderError> {
    let c = vec3(v, what)?;
    if c.min_element() < 0.0 {
        return Err(RenderError::Scene(format!("{what} is negative")));
    }
    Ok(c)
}

impl SceneFile {
    pub fn load(path: &Path) -> Result<SceneFile, RenderError> {
        let text = std::fs::read_to_string(path).map_err(|source| RenderError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path.parent())
    }

    /// Parses TOML text; relative env file paths resolve against `base`.
    pub fn parse(text: &str, base: Option<&Path>) -> Result<SceneFile, RenderError> {
        let mut f: SceneFile =
            toml::from_str(text).map_err(|e| RenderError::Scene(e.to_string()))?;
        if let (Some(env), Some(base)) = (&mut f.env, base)
            && let Some(file) = &mut env.file
            && Path::new(file.as_str()).is_relative()
        {
            *file = base.join(&*file).to_string_lossy().into_owned();
        }
        Ok(f)
    }

    /// The scene of built-in object `name` with the default lighting, scaled
    /// by the `[object]` table's scale (built-ins are in mm).
    pub fn builtin_scene(&self, name: &str) -> Result<Scene, RenderError> {
        let (scale, uv) = self.object()?;
        if uv.is_some() {
            return Err(RenderError::Scene(
                "object.uv_scale_mm applies to mesh files (--mesh); a built-in object has its own surface coordinates in mm"
                    .into(),
            ));
        }
        Ok(Scene::lit(builtin_mesh(name)?.scaled(scale)?))
    }

    /// The mesh scale and UV scale of the `[object]` table.
    pub fn object(&self) -> Result<(f32, Option<f32>), RenderError> {
        let o = self.object.as_ref();
        let scale = o.and_then(|o| o.scale).unwrap_or(1.0);
        let uv = o.and_then(|o| o.uv_scale_mm);
        if !(scale.is_finite() && scale > 0.0) {
            return Err(RenderError::Scene(format!(
                "object.scale {scale} must be a number > 0"
            )));
        }
        if let Some(u) = uv
            && !(u.is_finite() && u > 0.0)
        {
            return Err(RenderError::Scene(format!(
                "object.uv_scale_mm {u} must be > 0"
            )));
        }
        Ok((scale, uv))
    }

    /// Applies the camera, lights and env map to a scene (lights given in
    /// the file replace the scene's; an `[env]` table replaces its env map).
    pub fn apply_scene(&self, scene: &mut Scene) -> Result<(), RenderError> {
        if let Some(c) = &self.camera {
            let fov = c.fov_deg.unwrap_or(DEFAULT_FOV_DEG);
            if !(fov > 0.5 && fov < 179.0) {
                return Err(RenderError::Scene(format!(
                    "camera.fov_deg {fov} out of (0.5, 179)"
                )));
            }
            let fov_y = fov * PI / 180.0;
            // What is not given comes from the default framing at this fov;
            // a target alone keeps the default viewing direction and distance.
            let (lo, hi) = scene.mesh.bounds();
            let framed = frame_camera_fov(lo, hi, fov_y);
            let target = match c.target {
                Some(t) => vec3(t, "camera.target")?,
                None => framed.target,
            };
            let eye = match c.eye {
                Some(e) => vec3(e, "camera.eye")?,
                None => target + (framed.eye - framed.target),
            };
            scene.camera = Camera {
                eye,
                target,
                up: unit(c.up.unwrap_or([0.0, 0.0, 1.0]), "camera.up")?,
                fov_y,
            };
            if scene.camera.eye == scene.camera.target {
                return Err(RenderError::Scene("camera.eye equals camera.target".into()));
            }
        }
        if !self.lights.is_empty() {
            scene.lights = self
                .lights
                .iter()
                .map(|l| match l.kind.as_str() {
                    "directional" => Ok(Light::Directional {
                        to_light: unit(
                            l.direction.ok_or_else(|| {
                                RenderError::Scene("directional light needs direction".into())
                            })?,
                            "light direction",
                        )?,
                        irradiance: colour(l.irradiance.unwrap_or([1.0; 3]), "light irradiance")?,
                    }),
                    "point" => Ok(Light::Point {
                        position: vec3(
                            l.position.ok_or_else(|| {
                                RenderError::Scene("point light needs position".into())
                            })?,
                            "light position",
                        )?,
                        intensity: colour(l.intensity.unwrap_or([1.0; 3]), "light intensity")?,
                    }),
                    k => Err(RenderError::Scene(format!(
                        "light kind {k:?} (expected directional or point)"
                    ))),
                })
                .collect::<Result<_, _>>()?;
        }
        if let Some(e) = &self.env {
            let scale = e.scale.unwrap_or(1.0);
            if !(scale.is_finite() && scale >= 0.0) {
                return Err(RenderError::Scene(format!(
                    "env.scale {scale} must be >= 0"
                )));
            }
            let rot = e.rotate_deg.unwrap_or(0.0) * PI / 180.0;
            let mut env = match (&e.builtin, &e.file) {
                (Some(_), Some(_)) => {
                    return Err(RenderError::Scene(
                        "env: give builtin or file, not both".into(),
                    ));
                }
                (None, Some(file)) => EnvMap::load(Path::new(file), rot, scale)?,
                (Some(b), None) if b == "sky" => {
                    EnvMap::sky(unit(e.sun.unwrap_or([1.0, -1.0, 1.0]), "env.sun")?, scale)
                }
                (Some(b), None) if b == "studio" => EnvMap::studio(scale),
                (Some(b), None) if b == "none" => {
                    scene.env = None;
                    return Ok(());
                }
                (Some(b), None) => {
                    return Err(RenderError::Scene(format!(
                        "env.builtin {b:?} (expected sky, studio or none)"
                    )));
                }
                (None, None) => {
                    return Err(RenderError::Scene("env needs builtin or file".into()));
                }
            };
            env.rotation = rot;
            scene.env = Some(env);
            scene.env_visible = e.visible.unwrap_or(true);
        }
        Ok(())
    }

    /// Applies the `[render]` table to settings.
    pub fn apply_settings(&self, s: &mut RenderSettings) -> Result<(), RenderError> {
        let Some(r) = &self.render else {
            return Ok(());
        };
        if let Some(m) = &r.mode {
            s.mode = m.parse::<Mode>()?;
        }
        s.width = r.width.unwrap_or(s.width);
        s.height = r.height.unwrap_or(s.height);
        s.spp = r.spp.unwrap_or(s.spp);
        s.surface_samples = r.surface_samples.unwrap_or(s.surface_samples);
        s.epsilon = r.epsilon.unwrap_or(s.epsilon);
        s.env_samples = r.env_samples.unwrap_or(s.env_samples);
        s.light_samples = r.light_samples.unwrap_or(s.light_samples);
        s.local_radius_mm = r.local_radius_mm.unwrap_or(s.local_radius_mm);
        s.near_field = r.near_field.unwrap_or(s.near_field);
        s.geometry = r.geometry.unwrap_or(s.geometry);
        s.curvature = r.curvature.unwrap_or(s.curvature);
        s.indirect_rays = r.indirect_rays.unwrap_or(s.indirect_rays);
        s.seed = r.seed.unwrap_or(s.seed);
        s.synthesis = r.synthesis.unwrap_or(s.synthesis);
        s.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_scene_file_applies() {
        let text = r#"
            [camera]
            eye = [0, -100, 50]
            target = [0, 0, 0]
            fov_deg = 40
            [[lights]]
            kind = "directional"
            direction = [0, 0, 1]
            irradiance = [2, 2, 2]
            [[lights]]
            kind = "point"
            position = [0, 0, 100]
            intensity = [1000, 1000, 1000]
            [env]
            builtin = "sky"
            scale = 0.5
            [render]
            mode = "lrf-only"
            width = 64
            height = 48
        "#;
        let f = SceneFile::parse(text, None).unwrap();
        let mut scene = Scene::builtin("sphere").unwrap();
        f.apply_scene(&mut scene).unwrap();
        assert_eq!(scene.lights.len(), 2);
        assert!((scene.camera.fov_y - 40f32.to_radians()).abs() < 1e-6);
        let mut s = RenderSettings::default();
        f.apply_settings(&mut s).unwrap();
        assert_eq!((s.width, s.height, s.mode), (64, 48, Mode::LrfOnly));
    }

    #[test]
    fn a_camera_table_without_eye_or_target_takes_the_defaults() {
        let mut scene = Scene::builtin("sphere").unwrap();
        let default = scene.camera.clone();
        let f = SceneFile::parse("[camera]\n", None).unwrap();
        f.apply_scene(&mut scene).unwrap();
        assert_eq!(scene.camera.eye, default.eye);
        assert_eq!(scene.camera.target, default.target);
        // A narrower view moves the eye back along the same direction.
        let f = SceneFile::parse("[camera]\nfov_deg = 15", None).unwrap();
        f.apply_scene(&mut scene).unwrap();
        let (d0, d1) = (
            default.eye - default.target,
            scene.camera.eye - scene.camera.target,
        );
        assert!(d1.length() > 1.9 * d0.length(), "{d0} {d1}");
        assert!(d1.normalize().dot(d0.normalize()) > 0.9999);
        // A target alone keeps the default offset of the eye from it.
        let f = SceneFile::parse("[camera]\ntarget = [0, 0, 50]", None).unwrap();
        f.apply_scene(&mut scene).unwrap();
        assert_eq!(scene.camera.target, Vec3::new(0.0, 0.0, 50.0));
        assert!(((scene.camera.eye - scene.camera.target) - d0).length() < 1e-3);
    }

    #[test]
    fn object_scale_is_checked_and_applied_for_built_ins() {
        for (text, needle) in [
            ("[object]\nscale = 0", "object.scale 0 must be a number > 0"),
            ("[object]\nscale = -1", "object.scale -1 must be"),
            ("[object]\nscale = nan", "object.scale NaN must be"),
            ("[object]\nscale = 1e30", "out of range"),
            ("[object]\nuv_scale_mm = 5", "mesh files"),
        ] {
            let f = SceneFile::parse(text, None).unwrap();
            let e = f.builtin_scene("slab").err().expect(text).to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
        let f = SceneFile::parse("[object]\nscale = 2", None).unwrap();
        let (lo, hi) = f.builtin_scene("slab").unwrap().mesh.bounds();
        assert!(((hi - lo).x - 120.0).abs() < 1e-3, "{lo} {hi}");
    }

    #[test]
    fn bad_scene_files_give_clear_errors() {
        let cases = [
            ("[camera]\neye = [0,0,0]\ntarget = [0,0,0]", "equals"),
            ("[[lights]]\nkind = \"spot\"", "spot"),
            ("[[lights]]\nkind = \"directional\"", "needs direction"),
            ("[env]\nbuiltin = \"moon\"", "moon"),
            ("[render]\nmode = \"bogus\"", "bogus"),
            ("[render]\nwidth = 0", "width"),
            ("[camerra]\n", "unknown field"),
            ("[env]\nfile = \"/nonexistent.exr\"", "nonexistent"),
        ];
        for (text, needle) in cases {
            let mut scene = Scene::builtin("slab").unwrap();
            let mut s = RenderSettings::default();
            let r = SceneFile::parse(text, None).and_then(|f| {
                f.apply_scene(&mut scene)?;
                f.apply_settings(&mut s)
            });
            let e = r.expect_err(text).to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }
}
