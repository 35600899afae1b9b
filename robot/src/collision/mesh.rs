//! Mesh files a URDF names: where they are (`package://`, `file://` or a path relative to the URDF) and their
//! vertices (STL, binary or ASCII: what ROS descriptions use for collision geometry).

use std::path::{Path, PathBuf};

/// A mesh that cannot be found or read, named as the URDF names it.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {problem}")]
pub struct MeshError {
    pub file: String,
    pub problem: String,
}

impl MeshError {
    pub fn new(file: &Path, problem: impl Into<String>) -> Self {
        MeshError { file: file.display().to_string(), problem: problem.into() }
    }
}

/// The file a URDF at `urdf` means by `filename`. `package://NAME/REST` is looked for as ROS tools do, in
/// `ROS_PACKAGE_PATH` (`DIR/NAME/REST`) and `AMENT_PREFIX_PATH` (`PREFIX/share/NAME/REST`), and, for a description
/// unpacked outside a workspace, in the URDF's own ancestors (a directory called NAME, or holding one).
pub fn resolve(filename: &str, urdf: &Path) -> Result<PathBuf, MeshError> {
    // Absolute, so that the ancestors searched for a package go above the working directory too (a URDF named
    // `ur5.urdf` has the empty path as its parent, and that has no ancestors).
    let urdf = std::path::absolute(urdf).unwrap_or_else(|_| urdf.to_path_buf());
    let here = urdf.parent().unwrap_or(Path::new("/"));
    if let Some(path) = filename.strip_prefix("file://") {
        return exists(PathBuf::from(path), filename);
    }
    let Some(rest) = filename.strip_prefix("package://") else {
        return exists(here.join(filename), filename);
    };
    let (package, inner) = rest.split_once('/').unwrap_or((rest, ""));
    let var = |name: &str| std::env::var(name).unwrap_or_default();
    let ros = var("ROS_PACKAGE_PATH");
    let ament = var("AMENT_PREFIX_PATH");
    let mut candidates: Vec<PathBuf> =
        ros.split(':').filter(|d| !d.is_empty()).map(|d| Path::new(d).join(package)).collect();
    candidates.extend(ament.split(':').filter(|d| !d.is_empty()).map(|d| Path::new(d).join("share").join(package)));
    for dir in here.ancestors() {
        if dir.file_name().is_some_and(|n| n == package) {
            candidates.push(dir.to_path_buf());
        }
        candidates.push(dir.join(package));
    }
    candidates.into_iter().map(|root| root.join(inner)).find(|p| p.is_file()).ok_or_else(|| MeshError {
        file: filename.to_string(),
        problem: format!(
            "not found (package '{package}' is neither in ROS_PACKAGE_PATH, AMENT_PREFIX_PATH nor above {})",
            here.display()
        ),
    })
}

fn exists(path: PathBuf, filename: &str) -> Result<PathBuf, MeshError> {
    match path.is_file() {
        true => Ok(path),
        false => Err(MeshError { file: filename.to_string(), problem: format!("no such file {}", path.display()) }),
    }
}

/// The vertices of the STL file `path` (each triangle's three, repeats included).
pub fn read_stl(path: &Path) -> Result<Vec<[f64; 3]>, MeshError> {
    let bytes = std::fs::read(path).map_err(|e| MeshError::new(path, e.to_string()))?;
    if !path.extension().is_some_and(|e| e.eq_ignore_ascii_case("stl")) {
        return Err(MeshError::new(path, "only STL meshes are read for collision geometry; convert it to STL"));
    }
    // Binary: an 80-byte header, a triangle count, 50 bytes per triangle (normal, 3 vertices, attribute). An ASCII
    // file starts with "solid", which some binary headers do too: the size decides.
    let binary = bytes.len() >= 84 && {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
        n.checked_mul(50).and_then(|b| b.checked_add(84)) == Some(bytes.len())
    };
    if binary {
        let mut points = Vec::with_capacity((bytes.len() - 84) / 50 * 3);
        for t in bytes[84..].chunks_exact(50) {
            let f = |a: usize| f32::from_le_bytes([t[a], t[a + 1], t[a + 2], t[a + 3]]) as f64;
            // After the normal (12 bytes), three vertices of 12 bytes.
            points.extend((1..4).map(|v| [f(12 * v), f(12 * v + 4), f(12 * v + 8)]));
        }
        return Ok(points);
    }
    let text = std::str::from_utf8(&bytes).map_err(|_| MeshError::new(path, "neither binary nor ASCII STL"))?;
    let mut points = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let mut words = line.split_whitespace();
        if words.next() != Some("vertex") {
            continue;
        }
        let v: Vec<f64> = words.filter_map(|w| w.parse().ok()).collect();
        match v[..] {
            [x, y, z] => points.push([x, y, z]),
            _ => return Err(MeshError::new(path, format!("line {}: a vertex needs 3 numbers", k + 1))),
        }
    }
    if points.is_empty() {
        return Err(MeshError::new(path, "no triangles (neither binary nor ASCII STL)"));
    }
    Ok(points)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_and_ascii_stl_give_the_same_vertices() {
        let dir = tempfile::tempdir().unwrap();
        let tri = [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.5]];
        // A binary header may begin with "solid" too: the size tells them apart.
        let mut binary = b"solid but binary".to_vec();
        binary.resize(80, 0);
        binary.extend(1u32.to_le_bytes());
        binary.extend([0u8; 12]);
        for v in &tri {
            binary.extend(v.iter().flat_map(|c| c.to_le_bytes()));
        }
        binary.extend([0u8; 2]);
        let b = dir.path().join("t.stl");
        std::fs::write(&b, &binary).unwrap();
        let a = dir.path().join("a.STL");
        std::fs::write(
            &a,
            "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 2 0.5\n  endloop\n \
             endfacet\nendsolid t\n",
        )
        .unwrap();
        let expected: Vec<[f64; 3]> = tri.iter().map(|v| v.map(f64::from)).collect();
        assert_eq!(read_stl(&b).unwrap(), expected);
        assert_eq!(read_stl(&a).unwrap(), expected);
        std::fs::write(dir.path().join("bad.stl"), "solid x\n vertex 1 2\n").unwrap();
        let e = read_stl(&dir.path().join("bad.stl")).unwrap_err().to_string();
        assert!(e.contains("bad.stl") && e.contains("line 2"), "{e}");
        let e = read_stl(&dir.path().join("m.dae")).unwrap_err().to_string();
        assert!(e.contains("m.dae"), "{e}");
    }

    #[test]
    fn package_paths_are_found_above_the_urdf_or_named_when_not() {
        let dir = tempfile::tempdir().unwrap();
        let pkg = dir.path().join("share/my_arm");
        std::fs::create_dir_all(pkg.join("urdf")).unwrap();
        std::fs::create_dir_all(pkg.join("meshes")).unwrap();
        std::fs::write(pkg.join("meshes/l1.stl"), "").unwrap();
        let urdf = pkg.join("urdf/arm.urdf");
        assert_eq!(resolve("package://my_arm/meshes/l1.stl", &urdf).unwrap(), pkg.join("meshes/l1.stl"));
        assert_eq!(resolve("../meshes/l1.stl", &urdf).unwrap(), pkg.join("urdf/../meshes/l1.stl"));
        let e = resolve("package://other_arm/meshes/l1.stl", &urdf).unwrap_err().to_string();
        assert!(e.contains("package://other_arm/meshes/l1.stl") && e.contains("ROS_PACKAGE_PATH"), "{e}");
    }
}
