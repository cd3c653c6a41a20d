//! Reading float arrays from NumPy `.npy` files with every size checked before allocation.
//!
//! The shape in the header is multiplied with overflow checks, its data size compared with
//! [`MAX_NPY_BYTES`] and with the bytes that follow the header, which must match exactly: a
//! shape that claims more data than the file holds, or less (trailing bytes), is refused
//! before a value is read. `npyz` parses the header and decodes the values.

use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use crate::limits::{MAX_NPY_BYTES, checked_bytes, describe_bytes};

/// Why a `.npy` file could not be read; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a readable .npy file: {problem}", path.display())]
    Header { path: PathBuf, problem: String },
    #[error("{}: dtype {dtype}; expected float32 or float64", path.display())]
    Dtype { path: PathBuf, dtype: String },
    #[error(
        "{}: shape {shape:?} needs more than the {} of array data a .npy file may hold",
        path.display(), describe_bytes(*limit)
    )]
    TooLarge {
        path: PathBuf,
        shape: Vec<u64>,
        limit: u64,
    },
    #[error(
        "{}: shape {shape:?} needs {needed} bytes of data, the file holds {held} after its header",
        path.display()
    )]
    SizeMismatch {
        path: PathBuf,
        shape: Vec<u64>,
        needed: u64,
        held: u64,
    },
}

/// A float array as stored: its shape, whether it is Fortran-ordered, and its values in file
/// order.
#[derive(Clone, Debug, PartialEq)]
pub struct NpyArray<T> {
    pub shape: Vec<u64>,
    pub fortran: bool,
    pub values: Vec<T>,
}

/// Bytes before the array data: magic (6), version (2), header length (2 in version 1, 4 in
/// versions 2 and 3) and the header itself.
fn data_offset(path: &Path, file_len: u64) -> Result<u64, NpyError> {
    let header = |problem: &str| NpyError::Header {
        path: path.to_path_buf(),
        problem: problem.to_string(),
    };
    let mut prefix = [0u8; 12];
    let mut f = crate::input::open(path).map_err(|source| NpyError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let got = f
        .read(&mut prefix)
        .and_then(|n| {
            let mut total = n;
            while total < prefix.len() {
                match f.read(&mut prefix[total..])? {
                    0 => break,
                    k => total += k,
                }
            }
            Ok(total)
        })
        .map_err(|source| NpyError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    if got < 8 || &prefix[..6] != b"\x93NUMPY" {
        return Err(header("missing the \\x93NUMPY magic"));
    }
    let offset = match prefix[6] {
        1 if got >= 10 => 10 + u16::from_le_bytes([prefix[8], prefix[9]]) as u64,
        2 | 3 if got >= 12 => {
            12 + u32::from_le_bytes([prefix[8], prefix[9], prefix[10], prefix[11]]) as u64
        }
        1..=3 => return Err(header("the file ends inside its header")),
        v => return Err(header(&format!("format version {v} is not read"))),
    };
    if offset > file_len {
        return Err(header("the file ends inside its header"));
    }
    Ok(offset)
}

/// Reads a float32 or float64 array, converting values with `from_f32`/`from_f64`.
fn read<T>(
    path: &Path,
    from_f32: fn(f32) -> T,
    from_f64: fn(f64) -> T,
) -> Result<NpyArray<T>, NpyError> {
    let io = |source| NpyError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = crate::input::open(path).map_err(io)?;
    let file_len = file.metadata().map_err(io)?.len();
    let offset = data_offset(path, file_len)?;
    let npy = npyz::NpyFile::new(BufReader::new(file)).map_err(|e| NpyError::Header {
        path: path.to_path_buf(),
        problem: e.to_string(),
    })?;
    let shape = npy.shape().to_vec();
    let fortran = npy.order() == npyz::Order::Fortran;
    let descr = npy.dtype().descr();
    let item: u64 = match descr.as_str() {
        "'<f4'" | "'>f4'" => 4,
        "'<f8'" | "'>f8'" => 8,
        _ => {
            return Err(NpyError::Dtype {
                path: path.to_path_buf(),
                dtype: descr,
            });
        }
    };
    let needed = match checked_bytes(&shape, item) {
        Some(n) if n <= MAX_NPY_BYTES => n,
        _ => {
            return Err(NpyError::TooLarge {
                path: path.to_path_buf(),
                shape,
                limit: MAX_NPY_BYTES,
            });
        }
    };
    let held = file_len - offset;
    if needed != held {
        return Err(NpyError::SizeMismatch {
            path: path.to_path_buf(),
            shape,
            needed,
            held,
        });
    }
    let values = if item == 4 {
        npy.into_vec::<f32>()
            .map(|v| v.into_iter().map(from_f32).collect())
    } else {
        npy.into_vec::<f64>()
            .map(|v| v.into_iter().map(from_f64).collect())
    }
    .map_err(|e| NpyError::Header {
        path: path.to_path_buf(),
        problem: format!("cannot read the array data: {e}"),
    })?;
    Ok(NpyArray {
        shape,
        fortran,
        values,
    })
}

/// A float32 or float64 array as f32 (float64 values rounded).
pub fn read_f32(path: &Path) -> Result<NpyArray<f32>, NpyError> {
    read(path, |v| v, |v| v as f32)
}

/// A float32 or float64 array as f64 (exact).
pub fn read_f64(path: &Path) -> Result<NpyArray<f64>, NpyError> {
    read(path, f64::from, |v| v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A version 1 or 2 file with `dict` and `data`.
    fn npy(version: u8, dict: &str, data: &[u8]) -> Vec<u8> {
        let mut out = b"\x93NUMPY".to_vec();
        out.extend_from_slice(&[version, 0]);
        let header = format!("{dict}\n");
        if version == 1 {
            out.extend_from_slice(&(header.len() as u16).to_le_bytes());
        } else {
            out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        }
        out.extend_from_slice(header.as_bytes());
        out.extend_from_slice(data);
        out
    }

    fn read_bytes(bytes: &[u8]) -> Result<NpyArray<f64>, NpyError> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npy");
        std::fs::write(&path, bytes).unwrap();
        read_f64(&path)
    }

    #[test]
    fn sizes_are_checked_against_the_file_and_the_limit() {
        let data: Vec<u8> = [1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let dict =
            |shape: &str| format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
        for version in [1, 2] {
            let a = read_bytes(&npy(version, &dict("(2, 3)"), &data)).unwrap();
            assert_eq!(a.shape, [2, 3]);
            assert_eq!(a.values, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        }
        let err = |shape: &str, data: &[u8]| {
            read_bytes(&npy(1, &dict(shape), data))
                .unwrap_err()
                .to_string()
        };
        assert!(err("(2, 4)", &data).contains("needs 32 bytes"));
        assert!(err("(1, 3)", &data).contains("holds 24"));
        assert!(err("(4294967296, 4294967296)", &data).contains("1 GiB"));
        assert!(err("(268435457,)", &data).contains("1 GiB"));
        let bad = read_bytes(b"\x93NUMPY\x02\x00\x10")
            .unwrap_err()
            .to_string();
        assert!(bad.contains("ends inside its header"), "{bad}");
        let ints = read_bytes(&npy(
            1,
            "{'descr': '<i4', 'fortran_order': False, 'shape': (6,), }",
            &data,
        ));
        assert!(ints.unwrap_err().to_string().contains("dtype '<i4'"));
    }
}
