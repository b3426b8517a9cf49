//! A seeded mutator for the stable runner: the inputs of a run are a function
//! of its seed files, its seed and the case number, so any case can be
//! regenerated alone. Besides byte-level changes it rewrites numbers in text,
//! where the readers' headers (PCD `POINTS`, PLY `element vertex`, COCO
//! sizes, checkpoint widths) keep their most dangerous values.

use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// Numbers that break size arithmetic, bounds and float parsing.
const INTERESTING_TEXT: [&str; 18] = [
    "0",
    "-1",
    "1",
    "2",
    "255",
    "65536",
    "2147483648",
    "4294967296",
    "1000000000000",
    "4611686018427387904",
    "18446744073709551616",
    "-9223372036854775808",
    "nan",
    "inf",
    "-inf",
    "1e308",
    "1e-320",
    "0.5",
];

const INTERESTING_INTS: [u64; 10] = [0, 1, 0x7f, 0x80, 0xff, 0xffff, 0x7fff_ffff, 0xffff_ffff, 1 << 62, u64::MAX];

/// Case `case` of a run with `seed` over `seeds` (never empty).
pub fn case_input(seeds: &[Vec<u8>], seed: u64, case: u64) -> Vec<u8> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ case.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    let pick = |rng: &mut ChaCha8Rng| &seeds[rng.random_range(0..seeds.len())];
    // The first cases are the seeds themselves.
    if (case as usize) < seeds.len() {
        return seeds[case as usize].clone();
    }
    let mut data = pick(&mut rng).clone();
    let other = pick(&mut rng).clone();
    let rounds = 1 + rng.random_range(0..4);
    for _ in 0..rounds {
        mutate(&mut data, &other, &mut rng);
    }
    data
}

fn mutate(data: &mut Vec<u8>, other: &[u8], rng: &mut ChaCha8Rng) {
    let len = data.len();
    let at = |rng: &mut ChaCha8Rng, n: usize| if n == 0 { 0 } else { rng.random_range(0..n) };
    match rng.random_range(0..9) {
        0 if len > 0 => {
            let i = at(rng, len);
            data[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let i = at(rng, len);
            data[i] = [0u8, 0xff, 0x7f, 0x80, b'\n', b' ', b'-', b'9'][rng.random_range(0..8)];
        }
        2 => {
            let i = at(rng, len + 1);
            let n = 1 + rng.random_range(0..16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
            data.splice(i..i, bytes);
        }
        3 if len > 0 => {
            let i = at(rng, len);
            let n = 1 + at(rng, (len - i).min(256));
            data.drain(i..i + n);
        }
        4 if len > 0 => {
            // Duplicate a range (repeated records, repeated header lines).
            let i = at(rng, len);
            let n = 1 + at(rng, (len - i).min(512));
            let copy = data[i..i + n].to_vec();
            let j = at(rng, len + 1);
            data.splice(j..j, copy);
        }
        5 if len >= 8 => {
            let i = at(rng, len - 7);
            let v = INTERESTING_INTS[rng.random_range(0..INTERESTING_INTS.len())];
            let width = [1usize, 2, 4, 8][rng.random_range(0..4)];
            let bytes = if rng.random() { v.to_le_bytes() } else { v.to_be_bytes() };
            data[i..i + width].copy_from_slice(&bytes[..width]);
        }
        6 => replace_number(data, rng),
        7 if len > 0 => data.truncate(at(rng, len)),
        8 if !other.is_empty() => {
            // Splice: this input's head, another's tail.
            let i = at(rng, len + 1);
            let j = at(rng, other.len());
            data.truncate(i);
            data.extend_from_slice(&other[j..]);
        }
        _ => replace_number(data, rng),
    }
}

/// Replaces one run of ASCII digits (with its sign and decimals) by an
/// interesting number.
fn replace_number(data: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let starts: Vec<usize> = (0..data.len())
        .filter(|&i| data[i].is_ascii_digit() && (i == 0 || !data[i - 1].is_ascii_alphanumeric()))
        .collect();
    if starts.is_empty() {
        return;
    }
    let mut start = starts[rng.random_range(0..starts.len())];
    if start > 0 && data[start - 1] == b'-' {
        start -= 1;
    }
    let mut end = start + 1;
    while end < data.len() && (data[end].is_ascii_digit() || matches!(data[end], b'.' | b'e' | b'E' | b'+' | b'-')) {
        end += 1;
    }
    let value = INTERESTING_TEXT[rng.random_range(0..INTERESTING_TEXT.len())];
    data.splice(start..end, value.bytes());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_case_is_a_function_of_the_seeds_the_seed_and_its_number() {
        let seeds = vec![b"POINTS 10\nDATA ascii\n1 2 3\n".to_vec(), vec![0u8; 64]];
        assert_eq!(case_input(&seeds, 7, 0), seeds[0]);
        assert_eq!(case_input(&seeds, 7, 1), seeds[1]);
        let a: Vec<Vec<u8>> = (2..200).map(|k| case_input(&seeds, 7, k)).collect();
        let b: Vec<Vec<u8>> = (2..200).map(|k| case_input(&seeds, 7, k)).collect();
        assert_eq!(a, b);
        let other: Vec<Vec<u8>> = (2..200).map(|k| case_input(&seeds, 8, k)).collect();
        assert_ne!(a, other);
        // Mutations change the inputs, and numbers in text get rewritten.
        assert!(a.iter().filter(|d| !seeds.contains(d)).count() > 150);
        assert!(a.iter().any(|d| String::from_utf8_lossy(d).contains("1000000000000")));
    }
}
