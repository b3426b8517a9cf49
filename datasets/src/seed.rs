//! Seeded hashing: every random draw of the project (the simulated world,
//! its sensors, the trainer's shuffles) is a pure function of a seed and a
//! counter, so runs repeat exactly and parts draw independent numbers.

/// A 64-bit mixing function (SplitMix64's finaliser): turns seeds and
/// counters into well-spread, repeatable values.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A uniform value in [0, 1) from a hashed key.
pub fn unit(key: u64) -> f64 {
    (mix(key) >> 11) as f64 / (1u64 << 53) as f64
}
