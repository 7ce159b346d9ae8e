//! The unit tests' random numbers: one generator, seeded per test, so a failing case
//! replays from its seed.

/// Uniform numbers in [0, 1) from Knuth's 64-bit linear congruential generator, the top 53
/// bits of each state.
pub fn uniform(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed;
    move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}
