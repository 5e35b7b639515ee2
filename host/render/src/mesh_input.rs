//! The raw mesh a loader hands over (the OBJ and PLY readers, the built-in
//! objects), before [`crate::mesh::Mesh::build`] validates it: the one type
//! the readers and the mesh share, so neither imports the other.

/// Raw mesh data as a loader reads it, before validation.
#[derive(Clone, Debug, Default)]
pub struct MeshInput {
    pub positions: Vec<[f32; 3]>,
    pub normals: Option<Vec<[f32; 3]>>,
    /// Per-vertex texture coordinates in file units (usually 0..1).
    pub uvs: Option<Vec<[f32; 2]>>,
    pub triangles: Vec<[u32; 3]>,
}

impl MeshInput {
    /// Multiplies all positions by `s` (file units -> mm).
    pub fn scale(&mut self, s: f32) {
        for p in &mut self.positions {
            for c in p.iter_mut() {
                *c *= s;
            }
        }
    }
}
