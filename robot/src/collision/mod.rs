//! A robot's collision geometry as parry3d-f64 shapes (feature `collision`): URDF primitives as they are, meshes as
//! their convex hulls (what a distance query can use at thousands of poses a second; a hull only ever adds volume,
//! so a pose it calls free is free), placed in each body's frame.

mod mesh;

pub use mesh::{MeshError, read_stl, resolve};

use std::path::Path;

use parry3d_f64::math::{Mat3, Pose as ParryPose, Rot3, Vec3};
use parry3d_f64::shape::{Ball, Capsule, ConvexPolyhedron, Cuboid, Cylinder, Shape as ParryShape};

use crate::model::{Geometry, Shape};
use crate::spatial::Se3;

/// `x` as parry's pose.
pub fn pose(x: &Se3) -> ParryPose {
    let m = &x.rot;
    let mat = Mat3::from_cols(
        Vec3::new(m[(0, 0)], m[(1, 0)], m[(2, 0)]),
        Vec3::new(m[(0, 1)], m[(1, 1)], m[(2, 1)]),
        Vec3::new(m[(0, 2)], m[(1, 2)], m[(2, 2)]),
    );
    ParryPose::from_parts(Vec3::new(x.trans.x, x.trans.y, x.trans.z), Rot3::from_mat3(&mat).normalize())
}

/// The rotation that turns parry's cylinder axis (y) onto the URDF's (z): +90 degrees about x.
pub fn y_onto_z() -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::new(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0)
}

/// A shape placed in its body's frame.
pub struct Placed {
    pub shape: Box<dyn ParryShape>,
    pub offset: Se3,
}

/// The parry shape of `g`, meshes read through [`resolve`] from the URDF at `urdf`.
pub fn shape_of(g: &Geometry, urdf: &Path) -> Result<Placed, MeshError> {
    let mut offset = g.origin.se3();
    let shape: Box<dyn ParryShape> = match &g.shape {
        Shape::Box { size } => Box::new(Cuboid::new(Vec3::new(size[0] / 2.0, size[1] / 2.0, size[2] / 2.0))),
        Shape::Sphere { radius } => Box::new(Ball::new(*radius)),
        Shape::Capsule { radius, length } => Box::new(Capsule::new_z(length / 2.0, *radius)),
        Shape::Cylinder { radius, length } => {
            // URDF cylinders run along z, parry's along y.
            offset = offset.compose(&Se3::new(y_onto_z(), nalgebra::Vector3::zeros()));
            Box::new(Cylinder::new(length / 2.0, *radius))
        }
        Shape::Mesh { filename, scale } => {
            let path = resolve(filename, urdf)?;
            let s = scale.unwrap_or([1.0; 3]);
            let points: Vec<Vec3> =
                read_stl(&path)?.into_iter().map(|p| Vec3::new(p[0] * s[0], p[1] * s[1], p[2] * s[2])).collect();
            let hull = ConvexPolyhedron::from_convex_hull(&points)
                .ok_or_else(|| MeshError::new(&path, "its points span no volume (no convex hull)"))?;
            Box::new(hull)
        }
    };
    Ok(Placed { shape, offset })
}

#[cfg(test)]
mod tests {
    use crate::urdf::{Welds, collision_bodies};

    /// A tool welded on link 1 by a fixed joint turned 90 degrees about z: its sphere, 0.1 m along the tool's x,
    /// sits 0.1 m along link 1's y, 0.5 m up; the base keeps its own box.
    #[test]
    fn welded_geometry_joins_its_body_where_the_weld_puts_it() {
        let urdf = r#"<robot name="r">
  <link name="base"><collision><geometry><box size="1 1 0.1"/></geometry></collision></link>
  <link name="l1"><inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><cylinder radius="0.05" length="0.4"/></geometry></collision></link>
  <link name="tool"><collision><origin xyz="0.1 0 0"/><geometry><sphere radius="0.02"/></geometry></collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="weld" type="fixed"><parent link="l1"/><child link="tool"/><origin xyz="0 0 0.5" rpy="0 0 1.5707963267948966"/></joint>
</robot>"#;
        let bodies = collision_bodies(urdf, "r.urdf", &Welds::new()).unwrap();
        assert_eq!(bodies.len(), 2);
        assert_eq!(bodies[0].len(), 1);
        assert_eq!(bodies[1].len(), 2, "the link's cylinder and the tool's sphere");
        let sphere = bodies[1][1].origin.se3();
        let expected = nalgebra::Vector3::new(0.0, 0.1, 0.5);
        assert!((sphere.trans - expected).norm() < 1e-12, "{:?}", sphere.trans);
    }
}
