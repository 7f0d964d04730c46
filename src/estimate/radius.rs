//! The progressive radius schedule (the paper's eq. 3, Jarosz et al. 2011; Knaus and
//! Zwicker 2011): R_i = R_1 (prod_{k=1}^{i-1} (k + alpha) / k) / i, i.e.
//! R_{i+1} = R_i (i + alpha) / (i + 1). Beams (1D kernel) shrink their radius this way;
//! photons (2D kernel) shrink their radius squared this way, so both estimates keep the
//! same variance/bias balance and converge with alpha in (0, 1).

/// Factor R_i / R_1 of pass `i` (1-based).
pub fn shrink(i: u32, alpha: f32) -> f64 {
    let mut f = 1.0f64;
    for k in 1..i {
        f *= (k as f64 + alpha as f64) / (k as f64 + 1.0);
    }
    f
}

/// Beam radius of pass `i` (1-based).
pub fn beam_radius(r1: f32, i: u32, alpha: f32) -> f32 {
    (r1 as f64 * shrink(i, alpha)) as f32
}

/// Photon radius of pass `i` (1-based): its square follows eq. 3.
pub fn photon_radius(r1: f32, i: u32, alpha: f32) -> f32 {
    (r1 as f64 * shrink(i, alpha).sqrt()) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_eq3_product_form() {
        let alpha = 0.9f64;
        for i in 1..200u32 {
            let mut prod = 1.0f64;
            for k in 1..i {
                prod *= (k as f64 + alpha) / k as f64;
            }
            let eq3 = prod / i as f64;
            assert!((shrink(i, 0.9) - eq3).abs() < 1e-6 * eq3);
        }
    }

    #[test]
    fn shrinks_like_i_pow_alpha_minus_one() {
        // prod (k+a)/k ~ i^a / Gamma(1+a), so R_i ~ i^(a-1) / Gamma(1+a); Gamma(1.9) = 0.961766.
        let i = 100_000u32;
        let expect = (i as f64).powf(-0.1) / 0.961_765_8;
        assert!((shrink(i, 0.9) / expect - 1.0).abs() < 1e-3);
        assert_eq!(beam_radius(0.5, 1, 0.9), 0.5);
        assert!((photon_radius(0.5, 2, 0.9) - 0.5 * 0.95f32.sqrt()).abs() < 1e-6);
    }
}
