//! What the renderer needs from a material: the four parts of paper eq. 4,
//! as an interface. Its implementations are in [`crate::materials`]: an
//! acquired [`qhm_model::MaterialModel`] and the plain-dipole
//! [`crate::materials::Homogeneous`].
//!
//! Radiance convention (shared with qhm-model, docs/model-format.md):
//! L_o = ∫ R(x, w_i, w_o) E_n(w_i) dw_i + f_v(x, w_o) / pi · Σ_i R_d f E_i A_i,
//! with E_n the irradiance normal to the light.
//!
//! Directions are in the local shading frame: z = surface normal (outside),
//! x = the texture's +u direction on the surface.

use glam::Vec3;
use qhm_model::DipoleParams;

use crate::texture_synthesis::TexLookup;

/// The material interface of the renderer.
pub trait Material: Sync {
    /// The global dipole term (a', s'_t, eta).
    fn dipole(&self) -> DipoleParams;
    /// Mesostructure entrance function f(w_i), 1 at normal incidence.
    fn entrance(&self, wi: [f32; 3]) -> [f32; 3];
    /// Mesostructure exiting function f_v(x, w_o); `uv` in [0, 1)^2 of the
    /// material texture.
    fn exiting(&self, uv: [f32; 2], wo: [f32; 3]) -> [f32; 3];
    /// Local reflectance function R(x, w_i, w_o) (radiance per unit
    /// irradiance on a surface perpendicular to w_i; may be negative).
    fn lrf(&self, uv: [f32; 2], wi: [f32; 3], wo: [f32; 3]) -> [f32; 3];
    /// f_v blended over a lookup's texture coordinates (output-space
    /// filtering across the synthesis's cuts).
    fn exiting_blend(&self, tex: &TexLookup, wo: [f32; 3]) -> Vec3 {
        tex.blend(|uv| self.exiting(uv, wo))
    }
    /// R blended over a lookup's texture coordinates.
    fn lrf_blend(&self, tex: &TexLookup, wi: [f32; 3], wo: [f32; 3]) -> Vec3 {
        tex.blend(|uv| self.lrf(uv, wi, wo))
    }
    /// Texture size in texels (width, height).
    fn texture_size(&self) -> (u32, u32);
    /// Texel pitch on the sample, mm.
    fn texel_mm(&self) -> f32;
    /// False when the LRF is identically zero, so the renderer can skip
    /// integrating it.
    fn has_lrf(&self) -> bool {
        true
    }
    /// Radius of the local disc A_o (mm) whose scattering the LRF holds:
    /// eq. 4's dipole sum runs over the surface outside it. 0 = none. Only
    /// consulted when [`Material::has_lrf`].
    fn local_disc_mm(&self) -> f32 {
        0.0
    }
    /// True when f and f_v are the smooth surface's idealisation rather
    /// than measured (a homogeneous material: f = T(θ)/T(0), f_v = 1 at a
    /// single view). The renderer then adds what a smooth boundary does to
    /// a half-space of the material's albedo: on entry, the rise of the
    /// diffuse reflectance with the angle of incidence (an oblique beam
    /// scatters first nearer the surface; `qhm_model::radiative_transfer::
    /// oblique_reflectance`), and on exit the emergent radiance's shape
    /// S(w_o) (the Fresnel fall-off towards grazing, ∫ S cos dw_o / pi = 1).
    /// A fitted f and f_v are measured from stripe profiles at each light
    /// and view and hold both already.
    fn smooth_boundary(&self) -> bool {
        false
    }
}
