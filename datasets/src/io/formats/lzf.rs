//! LZF, the byte compressor behind PCL's `DATA binary_compressed` PCD files.
//!
//! A stream is a sequence of runs. A control byte below 32 starts a literal
//! run of `ctrl + 1` bytes. Otherwise its top three bits are a back-reference
//! length (7 means "add the next byte"), its low five bits the high part of
//! the offset, and the next byte the low part: copy `len + 2` bytes starting
//! `offset + 1` bytes back in the output.

/// Why a stream could not be decompressed, with the offset in the input.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LzfError {
    pub offset: usize,
    pub message: &'static str,
}

/// Decompresses `input`, which must expand to exactly `expected_len` bytes.
pub fn decompress(input: &[u8], expected_len: usize) -> Result<Vec<u8>, LzfError> {
    let mut out = Vec::with_capacity(expected_len);
    let mut i = 0;
    while i < input.len() {
        let ctrl = input[i] as usize;
        let at = i;
        i += 1;
        if ctrl < 32 {
            let run = ctrl + 1;
            if i + run > input.len() {
                return Err(LzfError { offset: at, message: "literal run past the end of the data" });
            }
            if out.len() + run > expected_len {
                return Err(LzfError { offset: at, message: "output longer than declared" });
            }
            out.extend_from_slice(&input[i..i + run]);
            i += run;
        } else {
            let mut len = ctrl >> 5;
            if len == 7 {
                let Some(&extra) = input.get(i) else {
                    return Err(LzfError { offset: at, message: "truncated back-reference" });
                };
                len += extra as usize;
                i += 1;
            }
            let Some(&low) = input.get(i) else {
                return Err(LzfError { offset: at, message: "truncated back-reference" });
            };
            i += 1;
            let back = ((ctrl & 0x1f) << 8) + low as usize + 1;
            if back > out.len() {
                return Err(LzfError { offset: at, message: "back-reference before the start of the output" });
            }
            let len = len + 2;
            if out.len() + len > expected_len {
                return Err(LzfError { offset: at, message: "output longer than declared" });
            }
            let start = out.len() - back;
            // Byte by byte: a reference may overlap the bytes it produces.
            for k in 0..len {
                out.push(out[start + k]);
            }
        }
    }
    if out.len() != expected_len {
        return Err(LzfError { offset: input.len(), message: "output shorter than declared" });
    }
    Ok(out)
}

const HASH_BITS: u32 = 14;
const MAX_OFFSET: usize = 1 << 13;
const MAX_LITERAL: usize = 32;
const MAX_MATCH: usize = 264;

/// Compresses `input` (greedy matching over a 3-byte hash, as liblzf does).
pub fn compress(input: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(input.len() / 2 + 16);
    let mut table = vec![usize::MAX; 1 << HASH_BITS];
    let mut literal_start = 0;
    let mut i = 0;
    while i + 2 < input.len() {
        let key = u32::from(input[i]) << 16 | u32::from(input[i + 1]) << 8 | u32::from(input[i + 2]);
        let slot = (key.wrapping_mul(2_654_435_761) >> (32 - HASH_BITS)) as usize;
        let candidate = table[slot];
        table[slot] = i;
        let usable = candidate != usize::MAX
            && i - candidate <= MAX_OFFSET
            && input[candidate..candidate + 3] == input[i..i + 3];
        if !usable {
            i += 1;
            continue;
        }
        let limit = (input.len() - i).min(MAX_MATCH);
        let mut len = 3;
        while len < limit && input[candidate + len] == input[i + len] {
            len += 1;
        }
        push_literals(&mut out, &input[literal_start..i]);
        let back = i - candidate - 1;
        let coded = len - 2;
        if coded < 7 {
            out.push(((coded << 5) | (back >> 8)) as u8);
        } else {
            out.push(((7 << 5) | (back >> 8)) as u8);
            out.push((coded - 7) as u8);
        }
        out.push((back & 0xff) as u8);
        i += len;
        literal_start = i;
    }
    push_literals(&mut out, &input[literal_start..]);
    out
}

fn push_literals(out: &mut Vec<u8>, mut bytes: &[u8]) {
    while !bytes.is_empty() {
        let run = bytes.len().min(MAX_LITERAL);
        out.push((run - 1) as u8);
        out.extend_from_slice(&bytes[..run]);
        bytes = &bytes[run..];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decodes_a_hand_made_stream() {
        // "abc" as literals, then a back-reference of length 6 at offset 3,
        // which overlaps itself: "abcabcabc".
        let stream = [2, b'a', b'b', b'c', (4 << 5), 2];
        assert_eq!(decompress(&stream, 9).unwrap(), b"abcabcabc");
    }

    #[test]
    fn round_trips_repetitive_and_random_bytes() {
        let mut state = 0x9e37_79b9_u32;
        let mut noise = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            state as u8
        };
        let mut data: Vec<u8> = (0..5000).map(|i| (i % 17) as u8).collect();
        data.extend((0..5000).map(|_| noise()));
        data.extend(std::iter::repeat_n(7u8, 3000));
        let packed = compress(&data);
        assert!(packed.len() < data.len(), "repetitive data must shrink");
        assert_eq!(decompress(&packed, data.len()).unwrap(), data);
        assert_eq!(decompress(&compress(&[]), 0).unwrap(), Vec::<u8>::new());
        assert_eq!(decompress(&compress(b"ab"), 2).unwrap(), b"ab");
    }

    #[test]
    fn rejects_corrupt_streams_with_offsets() {
        let err = decompress(&[5, b'a'], 6).unwrap_err();
        assert_eq!(err.offset, 0);
        let err = decompress(&[0, b'a', (1 << 5), 9], 4).unwrap_err();
        assert_eq!((err.offset, err.message), (2, "back-reference before the start of the output"));
        assert!(decompress(&[1, b'a', b'b'], 3).is_err());
    }
}
