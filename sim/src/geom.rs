//! Plane geometry shared by the simulator: vector aliases and the exact closest approach of two
//! bodies moving linearly.

/// A point or velocity in the world frame (metres, metres per second), double precision.
pub type Vec2 = nalgebra::Vector2<f64>;

/// Single-precision vector, used inside ORCA to reproduce RVO2's float32 arithmetic.
pub type Vec2f = nalgebra::Vector2<f32>;

/// Minimum over τ ∈ [0, horizon_s] of |p + w·τ|: the smallest centre distance reached by two
/// bodies whose relative position is `p` and relative velocity `w`, both moving linearly.
pub fn closest_approach(p: Vec2, w: Vec2, horizon_s: f64) -> f64 {
    let ww = w.norm_squared();
    let tau = if ww > 0.0 {
        (-p.dot(&w) / ww).clamp(0.0, horizon_s)
    } else {
        0.0
    };
    (p + w * tau).norm()
}

/// Wraps an angle into [−π, π).
pub fn wrap_angle(rad: f64) -> f64 {
    let two_pi = std::f64::consts::TAU;
    let wrapped = (rad + std::f64::consts::PI).rem_euclid(two_pi) - std::f64::consts::PI;
    // rem_euclid can return exactly TAU for tiny negative inputs through rounding.
    if wrapped >= std::f64::consts::PI {
        wrapped - two_pi
    } else {
        wrapped
    }
}

/// Unit vector of heading `rad`.
pub fn heading(rad: f64) -> Vec2 {
    Vec2::new(rad.cos(), rad.sin())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closest_approach_head_on_passes_through_zero() {
        // Relative position 2 m ahead, closing at 4 m/s: distance 0 at τ = 0.5 s.
        let d = closest_approach(Vec2::new(2.0, 0.0), Vec2::new(-4.0, 0.0), 1.0);
        assert!(d.abs() < 1e-12);
        // Horizon too short to reach it: 2 − 4·0.25 = 1.
        let d = closest_approach(Vec2::new(2.0, 0.0), Vec2::new(-4.0, 0.0), 0.25);
        assert!((d - 1.0).abs() < 1e-12);
    }

    #[test]
    fn closest_approach_receding_is_start_distance() {
        let d = closest_approach(Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), 10.0);
        assert!((d - 2f64.sqrt()).abs() < 1e-12);
        let d = closest_approach(Vec2::new(3.0, 4.0), Vec2::zeros(), 10.0);
        assert!((d - 5.0).abs() < 1e-12);
    }

    #[test]
    fn closest_approach_perpendicular_pass() {
        // Passing 1 m to the side.
        let d = closest_approach(Vec2::new(-2.0, 1.0), Vec2::new(1.0, 0.0), 10.0);
        assert!((d - 1.0).abs() < 1e-12);
    }

    #[test]
    fn wrap_angle_range() {
        for k in -20..20 {
            let a = k as f64 * 0.7;
            let w = wrap_angle(a);
            assert!(
                (-std::f64::consts::PI..std::f64::consts::PI).contains(&w),
                "{a} -> {w}"
            );
            assert!(
                ((a - w) / std::f64::consts::TAU).fract().abs() < 1e-9
                    || ((a - w) / std::f64::consts::TAU).fract().abs() > 1.0 - 1e-9
            );
        }
        assert_eq!(wrap_angle(std::f64::consts::PI), -std::f64::consts::PI);
    }
}
