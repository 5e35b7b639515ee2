//! The OBJ reader (through tobj): positions, and normals and texture
//! coordinates where every object of the file has them; faces triangulated.

use std::path::Path;

use crate::error::MeshError;
use crate::mesh_input::MeshInput;

/// Reads an OBJ file into raw mesh data, positions in file units.
pub fn read(path: &Path) -> Result<MeshInput, MeshError> {
    let opts = tobj::LoadOptions {
        single_index: true,
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _materials) = tobj::load_obj(path, &opts).map_err(|e| MeshError::Obj {
        path: path.to_path_buf(),
        message: match e {
            // tobj's own words for a file that is not OBJ text.
            tobj::LoadError::ReadError => "not readable as OBJ text".into(),
            e => e.to_string(),
        },
    })?;
    let mut out = MeshInput::default();
    let all_normals = models
        .iter()
        .all(|m| m.mesh.normals.len() == m.mesh.positions.len());
    let all_uvs = models
        .iter()
        .all(|m| m.mesh.texcoords.len() / 2 == m.mesh.positions.len() / 3);
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    for m in &models {
        let base = out.positions.len() as u32;
        let mesh = &m.mesh;
        out.positions
            .extend(mesh.positions.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        if all_normals {
            normals.extend(mesh.normals.chunks_exact(3).map(|p| [p[0], p[1], p[2]]));
        }
        if all_uvs {
            uvs.extend(mesh.texcoords.chunks_exact(2).map(|p| [p[0], p[1]]));
        }
        out.triangles.extend(
            mesh.indices
                .chunks_exact(3)
                .map(|t| [t[0] + base, t[1] + base, t[2] + base]),
        );
    }
    if all_normals && !normals.is_empty() {
        out.normals = Some(normals);
    }
    if all_uvs && !uvs.is_empty() {
        out.uvs = Some(uvs);
    }
    Ok(out)
}
