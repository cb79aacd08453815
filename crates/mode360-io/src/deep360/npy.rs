//! `.npy` and `.npz` (numpy's array file and its zip archive) for `f32`/`f64` arrays: what
//! Deep360 stores its depth in.

use super::error::Deep360Error;
use std::io::{Read, Write};
use std::path::Path;

/// Magic bytes at the start of every `.npy` file.
const NPY_MAGIC: &[u8] = b"\x93NUMPY";
/// Fixed part of an `.npy` v1 header: magic (6), version (2), header length (2).
const NPY_V1_PREFIX_BYTES: usize = 10;
/// Fixed part of an `.npy` v2/v3 header: magic (6), version (2), header length (4).
const NPY_V2_PREFIX_BYTES: usize = 12;
/// `.npy` headers are padded so the data starts on this alignment.
const NPY_ALIGN_BYTES: usize = 64;

/// A dense row-major `f32` array read from `.npy`.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Parses an `.npy` file (versions 1-3) holding little-endian `f4` or `f8` in C order.
/// `f8` values are narrowed to `f32`.
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    if bytes.len() < NPY_V1_PREFIX_BYTES || &bytes[..NPY_MAGIC.len()] != NPY_MAGIC {
        return Err("missing .npy magic".into());
    }
    let major = bytes[NPY_MAGIC.len()];
    let (header_len, prefix) = match major {
        1 => (
            u16::from_le_bytes([bytes[8], bytes[9]]) as usize,
            NPY_V1_PREFIX_BYTES,
        ),
        2 | 3 => {
            if bytes.len() < NPY_V2_PREFIX_BYTES {
                return Err("truncated .npy header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                NPY_V2_PREFIX_BYTES,
            )
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let header_end = prefix + header_len;
    let header = bytes
        .get(prefix..header_end)
        .ok_or_else(|| "truncated .npy header".to_string())?;
    let header = std::str::from_utf8(header).map_err(|_| "header is not text".to_string())?;
    let descr = header_value(header, "descr")?;
    let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
    let fortran = header_value(header, "fortran_order")?;
    if fortran.trim().starts_with("True") {
        return Err("Fortran-order arrays are not supported (expected C order)".into());
    }
    let shape_text = header_value(header, "shape")?;
    let shape_inner = shape_text
        .trim()
        .strip_prefix('(')
        .and_then(|s| s.split(')').next())
        .ok_or_else(|| format!("malformed shape '{shape_text}'"))?;
    let shape = shape_inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad dimension '{s}'"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let count: usize = shape.iter().product();
    let payload = &bytes[header_end..];
    let data = match descr {
        "<f4" | "f4" => {
            check_payload(payload, count, 4)?;
            payload[..count * 4]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        }
        "<f8" | "f8" => {
            check_payload(payload, count, 8)?;
            payload[..count * 8]
                .chunks_exact(8)
                .map(|c| {
                    let mut b = [0u8; 8];
                    b.copy_from_slice(c);
                    f64::from_le_bytes(b) as f32
                })
                .collect()
        }
        other => return Err(format!("unsupported dtype '{other}' (need <f4 or <f8)")),
    };
    Ok(NpyArray { shape, data })
}

fn check_payload(payload: &[u8], count: usize, elem_bytes: usize) -> Result<(), String> {
    if payload.len() < count * elem_bytes {
        return Err(format!(
            "data truncated: {} bytes for {count} values of {elem_bytes} bytes",
            payload.len()
        ));
    }
    Ok(())
}

/// The text after `'key':` in a `.npy` header dict, up to the next top-level comma.
fn header_value<'a>(header: &'a str, key: &str) -> Result<&'a str, String> {
    let pat = format!("'{key}':");
    let start = header
        .find(&pat)
        .ok_or_else(|| format!("header has no '{key}'"))?
        + pat.len();
    let rest = &header[start..];
    let mut depth = 0i32;
    for (k, ch) in rest.char_indices() {
        match ch {
            '(' => depth += 1,
            ')' => depth -= 1,
            ',' | '}' if depth == 0 => return Ok(&rest[..k]),
            _ => {}
        }
    }
    Ok(rest)
}

/// Serializes a little-endian `f4` C-order `.npy` (version 1).
pub fn write_npy(shape: &[usize], data: &[f32]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_text}, }}");
    let unpadded = NPY_V1_PREFIX_BYTES + header.len() + 1;
    let pad = (NPY_ALIGN_BYTES - unpadded % NPY_ALIGN_BYTES) % NPY_ALIGN_BYTES;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut out = Vec::with_capacity(NPY_V1_PREFIX_BYTES + header.len() + data.len() * 4);
    out.extend_from_slice(NPY_MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Reads array `key` (file `key.npy` inside the archive) from an `.npz`.
pub fn read_npz_array(path: &Path, key: &str) -> Result<NpyArray, Deep360Error> {
    let p = path.display().to_string();
    let file = std::fs::File::open(path).map_err(|source| Deep360Error::Io {
        path: p.clone(),
        source,
    })?;
    let mut archive = zip::ZipArchive::new(file).map_err(|e| Deep360Error::Npz {
        path: p.clone(),
        message: e.to_string(),
    })?;
    let mut entry = archive
        .by_name(&format!("{key}.npy"))
        .map_err(|e| Deep360Error::Npz {
            path: p.clone(),
            message: format!("no array '{key}': {e}"),
        })?;
    let mut bytes = Vec::new();
    entry
        .read_to_end(&mut bytes)
        .map_err(|source| Deep360Error::Io {
            path: p.clone(),
            source,
        })?;
    parse_npy(&bytes).map_err(|message| Deep360Error::Npy {
        path: p,
        key: key.into(),
        message,
    })
}

/// Writes a single-array `.npz` (deflate-compressed, like `numpy.savez_compressed`).
pub fn write_npz(
    path: &Path,
    key: &str,
    shape: &[usize],
    data: &[f32],
) -> Result<(), Deep360Error> {
    let p = path.display().to_string();
    let io = |source: std::io::Error| Deep360Error::Io {
        path: p.clone(),
        source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut zw = zip::ZipWriter::new(file);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    let zerr = |e: zip::result::ZipError| Deep360Error::Npz {
        path: p.clone(),
        message: e.to_string(),
    };
    zw.start_file(format!("{key}.npy"), opts).map_err(zerr)?;
    zw.write_all(&write_npy(shape, data)).map_err(io)?;
    zw.finish().map_err(zerr)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_errors() {
        let data: Vec<f32> = (0..12).map(|k| k as f32 * 0.5 - 1.0).collect();
        let bytes = write_npy(&[3, 4], &data);
        assert_eq!((bytes.len() - data.len() * 4) % NPY_ALIGN_BYTES, 0);
        let arr = parse_npy(&bytes).unwrap();
        assert_eq!(arr.shape, vec![3, 4]);
        assert_eq!(arr.data, data);
        assert!(parse_npy(b"not an npy file").is_err());
        let truncated = &bytes[..bytes.len() - 4];
        assert!(parse_npy(truncated).unwrap_err().contains("truncated"));
    }
}
