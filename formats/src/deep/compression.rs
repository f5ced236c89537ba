//! Deep chunks' compression: NONE, RLE and ZIPS, each behind OpenEXR's byte split and delta
//! predictor, and parts stored raw where compressing would not make them smaller.

use super::*;

/// The bytes of a chunk part after its compression: `packed` unpacked to exactly `expected`
/// bytes. A part stored no smaller than it unpacks is raw (what OpenEXR writes when
/// compressing would not pay).
pub(super) fn uncompress(
    compression: DeepCompression,
    packed: &[u8],
    expected: usize,
) -> Result<Vec<u8>, String> {
    if compression == DeepCompression::None || packed.len() >= expected {
        if packed.len() != expected {
            return Err(format!(
                "{} bytes stored, {expected} expected",
                packed.len()
            ));
        }
        return Ok(packed.to_vec());
    }
    let mut split = match compression {
        DeepCompression::Rle => rle_decode(packed, expected)?,
        DeepCompression::Zips => {
            miniz_oxide::inflate::decompress_to_vec_zlib_with_limit(packed, expected)
                .map_err(|e| format!("zlib: {:?}", e.status))?
        }
        DeepCompression::None => unreachable!("handled above"),
    };
    if split.len() != expected {
        return Err(format!(
            "unpacks to {} bytes, {expected} expected",
            split.len()
        ));
    }
    // Undo the delta predictor, then the split into even and odd bytes.
    for i in 1..split.len() {
        split[i] = split[i - 1].wrapping_add(split[i]).wrapping_sub(128);
    }
    let half = split.len().div_ceil(2);
    let mut out = Vec::with_capacity(expected);
    for k in 0..half {
        out.push(split[k]);
        if half + k < split.len() {
            out.push(split[half + k]);
        }
    }
    Ok(out)
}

/// `raw` compressed as OpenEXR does (byte split, delta predictor, then RLE or zlib); raw
/// where that is not smaller.
pub(super) fn compress(compression: DeepCompression, raw: &[u8]) -> Vec<u8> {
    if compression == DeepCompression::None || raw.is_empty() {
        return raw.to_vec();
    }
    let half = raw.len().div_ceil(2);
    let mut split: Vec<u8> = Vec::with_capacity(raw.len());
    split.extend(raw.iter().step_by(2));
    split.extend(raw.iter().skip(1).step_by(2));
    debug_assert_eq!(split.len(), raw.len());
    debug_assert!(half <= split.len());
    for i in (1..split.len()).rev() {
        split[i] = split[i].wrapping_sub(split[i - 1]).wrapping_add(128);
    }
    let packed = match compression {
        DeepCompression::Rle => rle_encode(&split),
        DeepCompression::Zips => miniz_oxide::deflate::compress_to_vec_zlib(&split, 6),
        DeepCompression::None => unreachable!("handled above"),
    };
    if packed.len() < raw.len() {
        packed
    } else {
        raw.to_vec()
    }
}

/// OpenEXR's run-length code: a signed count byte; `n >= 0`: the next byte `n + 1` times;
/// `n < 0`: `-n` bytes as they are.
pub(super) fn rle_decode(packed: &[u8], expected: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::with_capacity(expected);
    let mut at = 0;
    while at < packed.len() {
        let count = packed[at] as i8;
        at += 1;
        if count < 0 {
            let n = usize::from(count.unsigned_abs());
            let literal = packed
                .get(at..at + n)
                .ok_or("a literal run overruns the data")?;
            out.extend_from_slice(literal);
            at += n;
        } else {
            let byte = *packed.get(at).ok_or("a repeat run has no byte")?;
            at += 1;
            out.extend(std::iter::repeat_n(byte, count as usize + 1));
        }
        if out.len() > expected {
            return Err(format!("unpacks to more than {expected} bytes"));
        }
    }
    Ok(out)
}

/// The encoder of [`rle_decode`]'s code, as OpenEXR's `rleCompress`: runs of three or more
/// equal bytes (up to 128) as repeats, the rest as literals (up to 127).
pub(super) fn rle_encode(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(raw.len() + raw.len() / 64 + 2);
    let n = raw.len();
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && raw[end] == raw[start] && end - start < 128 {
            end += 1;
        }
        if end - start >= 3 {
            out.push((end - start - 1) as u8);
            out.push(raw[start]);
            start = end;
        } else {
            while end < n
                && !(end + 2 < n && raw[end] == raw[end + 1] && raw[end + 1] == raw[end + 2])
                && end - start < 127
            {
                end += 1;
            }
            out.push((-((end - start) as i32)) as i8 as u8);
            out.extend_from_slice(&raw[start..end]);
            start = end;
        }
    }
    out
}
