//! Link bodies: prismatic beams of a given cross-section with a linear density gradient along their length.
//!
//! A link of length `L` extends along +z of its frame from the joint (z = 0) to the next joint (z = L). Its
//! density varies linearly, `rho(z) = rho0 (1 + g (2 z / L - 1))` with `|g| < 1`, which moves the centre of mass to
//! `z_c = L (1/2 + g/6)` while keeping the mean density `rho0`, and changes the axial second moment to
//! `L^2/4 (1/3 - g^2/9)` (both exact: the integrands are polynomials). Every cross-section used here is symmetric
//! enough that its in-plane second moments are equal (`I_x = I_y = J/2`), so the inertia about the COM is
//! diagonal in the link frame:
//! `Ixx = Iyy = m (k_t^2 + Var(z))`, `Izz = m k_a^2`, with `k_t^2 = I_x / A` and `k_a^2 = J / A`.

use dynforge_proto::generator::SectionKind;

/// A concrete cross-section.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Section {
    /// Solid circle of diameter `d`.
    Solid { d: f64 },
    /// Hollow tube of outer diameter `d` and wall thickness `wall` (< d / 2).
    Tube { d: f64, wall: f64 },
    /// Square of side `d`.
    Square { d: f64 },
    /// Regular hexagon `d` across flats.
    Hexagon { d: f64 },
}

impl Section {
    /// Area [m^2].
    pub fn area(&self) -> f64 {
        use std::f64::consts::PI;
        match *self {
            Section::Solid { d } => PI * d * d / 4.0,
            Section::Tube { d, wall } => {
                let di = d - 2.0 * wall;
                PI * (d * d - di * di) / 4.0
            }
            Section::Square { d } => d * d,
            Section::Hexagon { d } => {
                let r = d / 3f64.sqrt();
                1.5 * 3f64.sqrt() * r * r
            }
        }
    }

    /// In-plane (bending) squared radius of gyration `I_x / A` [m^2].
    pub fn k2_transverse(&self) -> f64 {
        match *self {
            Section::Solid { d } => d * d / 16.0,
            Section::Tube { d, wall } => {
                let di = d - 2.0 * wall;
                (d * d + di * di) / 16.0
            }
            Section::Square { d } => d * d / 12.0,
            Section::Hexagon { d } => {
                let r = d / 3f64.sqrt();
                5.0 * r * r / 24.0
            }
        }
    }

    /// Polar squared radius of gyration `J / A` [m^2] (twice the transverse one for these sections).
    pub fn k2_axial(&self) -> f64 {
        2.0 * self.k2_transverse()
    }

    /// Radius of the smallest cylinder containing the section (for collision envelopes).
    pub fn circumradius(&self) -> f64 {
        match *self {
            Section::Solid { d } | Section::Tube { d, .. } => d / 2.0,
            Section::Square { d } => d / 2f64.sqrt(),
            Section::Hexagon { d } => d / 3f64.sqrt(),
        }
    }

    pub fn kind(&self) -> SectionKind {
        match self {
            Section::Solid { .. } => SectionKind::Solid,
            Section::Tube { .. } => SectionKind::Tube,
            Section::Square { .. } => SectionKind::Square,
            Section::Hexagon { .. } => SectionKind::Hexagon,
        }
    }

    /// Outer diameter / width across flats.
    pub fn diameter(&self) -> f64 {
        match *self {
            Section::Solid { d } | Section::Tube { d, .. } | Section::Square { d } | Section::Hexagon { d } => d,
        }
    }
}

/// A link body: a beam along +z of length `length`, density gradient `gradient` in (-1, 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Beam {
    pub section: Section,
    pub length: f64,
    pub gradient: f64,
    /// Mean density [kg/m^3].
    pub density: f64,
}

/// Mass, COM along z, and the diagonal of the inertia about the COM (link axes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BeamInertia {
    pub mass: f64,
    pub com_z: f64,
    pub ixx: f64,
    pub iyy: f64,
    pub izz: f64,
}

impl Beam {
    pub fn inertia(&self) -> BeamInertia {
        let (l, g) = (self.length, self.gradient);
        let mass = self.density * self.section.area() * l;
        let var_z = l * l / 4.0 * (1.0 / 3.0 - g * g / 9.0);
        let transverse = mass * (self.section.k2_transverse() + var_z);
        BeamInertia {
            mass,
            com_z: l * (0.5 + g / 6.0),
            ixx: transverse,
            iyy: transverse,
            izz: mass * self.section.k2_axial(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Area and second moment about the x axis of a simple polygon (shoelace-type formulas), an independent check of
    /// the closed forms for the polygonal sections and, in the limit of many sides, the circle.
    fn polygon_moments(pts: &[(f64, f64)]) -> (f64, f64, f64) {
        let (mut a, mut ix, mut iy) = (0.0, 0.0, 0.0);
        for k in 0..pts.len() {
            let (x0, y0) = pts[k];
            let (x1, y1) = pts[(k + 1) % pts.len()];
            let cross = x0 * y1 - x1 * y0;
            a += cross / 2.0;
            ix += cross * (y0 * y0 + y0 * y1 + y1 * y1) / 12.0;
            iy += cross * (x0 * x0 + x0 * x1 + x1 * x1) / 12.0;
        }
        (a, ix, iy)
    }

    fn regular(n: usize, circumradius: f64, phase: f64) -> Vec<(f64, f64)> {
        (0..n)
            .map(|k| {
                let t = phase + 2.0 * std::f64::consts::PI * k as f64 / n as f64;
                (circumradius * t.cos(), circumradius * t.sin())
            })
            .collect()
    }

    #[test]
    fn polygon_sections_match_the_shoelace_reference() {
        let d = 0.08;
        for (section, pts) in [
            (Section::Square { d }, regular(4, d / 2f64.sqrt(), std::f64::consts::FRAC_PI_4)),
            (Section::Hexagon { d }, regular(6, d / 3f64.sqrt(), 0.0)),
        ] {
            let (a, ix, iy) = polygon_moments(&pts);
            assert!((a - section.area()).abs() < 1e-15, "{section:?}");
            assert!((ix / a - section.k2_transverse()).abs() < 1e-15, "{section:?}");
            assert!((iy / a - section.k2_transverse()).abs() < 1e-15, "{section:?}");
            assert!(((ix + iy) / a - section.k2_axial()).abs() < 1e-15, "{section:?}");
        }
    }

    #[test]
    fn round_sections_are_the_limit_of_regular_polygons() {
        // For an inscribed n-gon the area error is O(1/n^2): with n = 20000 the relative error is ~1.6e-8.
        let (d, wall, n) = (0.1, 0.012, 20_000);
        let (ao, ixo, _) = polygon_moments(&regular(n, d / 2.0, 0.0));
        let (ai, ixi, _) = polygon_moments(&regular(n, d / 2.0 - wall, 0.0));
        let solid = Section::Solid { d };
        let tube = Section::Tube { d, wall };
        assert!((ao / solid.area() - 1.0).abs() < 1e-7);
        assert!((ixo / ao / solid.k2_transverse() - 1.0).abs() < 1e-7);
        assert!(((ao - ai) / tube.area() - 1.0).abs() < 1e-7);
        assert!(((ixo - ixi) / (ao - ai) / tube.k2_transverse() - 1.0).abs() < 1e-7);
    }

    #[test]
    fn beam_axial_moments_match_simpson_quadrature() {
        // rho(z) (z - c)^k is a polynomial of degree <= 3 in z, so Simpson's rule is exact up to rounding.
        let beam = Beam { section: Section::Hexagon { d: 0.07 }, length: 0.39, gradient: -0.63, density: 2700.0 };
        let b = beam.inertia();
        let lambda =
            |z: f64| beam.density * beam.section.area() * (1.0 + beam.gradient * (2.0 * z / beam.length - 1.0));
        let simpson =
            |f: &dyn Fn(f64) -> f64| beam.length / 6.0 * (f(0.0) + 4.0 * f(beam.length / 2.0) + f(beam.length));
        let m = simpson(&|z| lambda(z));
        let c = simpson(&|z| lambda(z) * z) / m;
        let second = simpson(&|z| lambda(z) * (z - c).powi(2));
        assert!((m - b.mass).abs() < 1e-12 * m);
        assert!((c - b.com_z).abs() < 1e-14);
        let want_ixx = second + m * beam.section.k2_transverse();
        assert!((want_ixx - b.ixx).abs() < 1e-12 * want_ixx);
    }
}
