//! Numpy arrays, from a `.npy` file or an entry of an `.npz` archive: the header checked
//! before npyz sees it, the data converted to `f64` in C order.

use kinetree_core::{Error, Result};
use std::io::{Cursor, Read};

/// An array read from npy data: its shape and its values in C (row-major) order.
#[derive(Debug)]
pub(crate) struct Array {
    /// The dimensions.
    pub shape: Vec<u64>,
    /// `shape`'s product of values, as `f64` (booleans as 0 and 1).
    pub values: Vec<f64>,
}

/// Element types [`read_array`] converts: little-endian floats, integers and booleans.
const KNOWN_TYPES: &str = "float64, float32, bool or an integer type";

/// The `shape` an npy header declares, read from its first bytes before npyz sees them: npyz
/// multiplies the dimensions unchecked (a panic in debug builds, a wrapped count in release
/// ones), so a hostile header must be refused first. Returns the bytes read (to be handed on
/// with the rest of the stream) and the shape, `None` when the header cannot be read this
/// way; npyz then reports what is wrong with it.
fn declared_shape(reader: &mut impl Read) -> Result<(Vec<u8>, Option<Vec<u128>>)> {
    let mut start = Vec::with_capacity(12);
    reader.by_ref().take(12).read_to_end(&mut start)?;
    if start.len() < 12 || &start[..6] != b"\x93NUMPY" {
        return Ok((start, None));
    }
    let (len, skip) = match start[6] {
        1 => (usize::from(u16::from_le_bytes([start[8], start[9]])), 10),
        _ => (
            u32::from_le_bytes([start[8], start[9], start[10], start[11]]) as usize,
            12,
        ),
    };
    // Headers are a few hundred bytes; a longer one is left to npyz.
    if len > 1 << 16 {
        return Ok((start, None));
    }
    let want = (skip + len).saturating_sub(start.len());
    let mut head = start;
    reader.by_ref().take(want as u64).read_to_end(&mut head)?;
    if head.len() < skip + len {
        return Ok((head, None));
    }
    let text = String::from_utf8_lossy(&head[skip..skip + len]).into_owned();
    let Some(after) = text.split_once("'shape'").map(|(_, a)| a) else {
        return Ok((head, None));
    };
    let Some(inside) = after
        .split_once('(')
        .and_then(|(_, a)| a.split_once(')'))
        .map(|(i, _)| i)
    else {
        return Ok((head, None));
    };
    let dims: Option<Vec<u128>> = inside
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.trim_end_matches('L').parse().ok())
        .collect();
    Ok((head, dims))
}

/// Refuses a shape whose data, at `item_bytes` per value, would not fit in the `data_len`
/// bytes there are, or whose strides (npyz multiplies the dimensions, zero-sized ones left
/// out) overflow 64 bits.
pub(crate) fn check_shape(dims: &[u128], item_bytes: u128, data_len: u64) -> Result<()> {
    let bytes = dims
        .iter()
        .try_fold(item_bytes, |acc, &d| acc.checked_mul(d))
        .filter(|&b| b <= u128::from(data_len));
    let strides_fit = dims
        .iter()
        .try_fold(8u128, |acc, &d| acc.checked_mul(d.max(1)))
        .is_some_and(|b| b <= u128::from(u64::MAX));
    if bytes.is_none() || !strides_fit {
        return Err(Error::Malformed {
            position: "header".into(),
            message: format!("shape {dims:?} needs more data than the {data_len} bytes there are"),
        });
    }
    Ok(())
}

/// Reads one array from npy data of `data_len` bytes. `check` sees the shape and the type
/// string before the values are allocated, to refuse the wrong shape or a size beyond the
/// memory limit.
///
/// # Errors
/// [`Error::Malformed`] for a bad header or truncated data, [`Error::DType`] for a type that
/// is not converted, and `check`'s errors.
pub(crate) fn read_array(
    mut reader: impl Read,
    data_len: u64,
    check: impl FnOnce(&[u64], &str) -> Result<()>,
) -> Result<Array> {
    let (head, dims) = declared_shape(&mut reader)?;
    if let Some(dims) = &dims {
        check_shape(dims, 1, data_len)?;
    }
    let npy =
        npyz::NpyFile::new(Cursor::new(head).chain(reader)).map_err(|e| Error::Malformed {
            position: "header".into(),
            message: e.to_string(),
        })?;
    let dtype = match &npy.dtype() {
        npyz::DType::Plain(t) => t.to_string(),
        other => format!("{other:?}"),
    };
    let shape = npy.shape().to_vec();
    let item_bytes: u128 = match dtype.as_str() {
        "<f8" | "<i8" | "<u8" => 8,
        "<f4" | "<i4" | "<u4" => 4,
        "<i2" | "<u2" => 2,
        "|b1" | "|i1" | "|u1" => 1,
        _ => {
            return Err(Error::DType {
                expected: KNOWN_TYPES.into(),
                found: dtype,
            });
        }
    };
    let dims: Vec<u128> = shape.iter().map(|&d| u128::from(d)).collect();
    check_shape(&dims, item_bytes, data_len)?;
    check(&shape, &dtype)?;
    let order = npy.order();
    // The element count is the header's, checked against the data's length and the memory
    // limit above, so the values are read into one buffer of their exact size (collecting
    // npyz's iterator grows a buffer by doubling, up to twice the data's size).
    let len = shape.iter().product::<u64>() as usize;
    let values: Vec<f64> = match dtype.as_str() {
        "<f8" => read_as_f64::<f64, _>(npy, len, |v| v),
        "<f4" => read_as_f64::<f32, _>(npy, len, f64::from),
        "<i4" => read_as_f64::<i32, _>(npy, len, f64::from),
        "<u4" => read_as_f64::<u32, _>(npy, len, f64::from),
        "<i2" => read_as_f64::<i16, _>(npy, len, f64::from),
        "<u2" => read_as_f64::<u16, _>(npy, len, f64::from),
        "|i1" => read_as_f64::<i8, _>(npy, len, f64::from),
        "|u1" => read_as_f64::<u8, _>(npy, len, f64::from),
        "|b1" => read_as_f64::<bool, _>(npy, len, |b| f64::from(u8::from(b))),
        // 64-bit integers: the values that matter here (flags, counts) are exact in f64.
        "<i8" => read_as_f64::<i64, _>(npy, len, |v| v as f64),
        _ => read_as_f64::<u64, _>(npy, len, |v| v as f64),
    }?;
    let values = if order == npyz::Order::Fortran && shape.len() > 1 {
        to_c_order(&shape, &values)
    } else {
        values
    };
    Ok(Array { shape, values })
}

/// The `len` values of `npy`'s data, each converted by `convert`.
///
/// # Errors
/// [`Error::Malformed`] at the data for a read error or a type npyz cannot read as `T`.
fn read_as_f64<T: npyz::Deserialize, R: Read>(
    npy: npyz::NpyFile<R>,
    len: usize,
    convert: impl Fn(T) -> f64,
) -> Result<Vec<f64>> {
    let bad_data = |message: String| Error::Malformed {
        position: "data".into(),
        message,
    };
    let data = npy.data::<T>().map_err(|e| bad_data(e.to_string()))?;
    let mut values = Vec::with_capacity(len);
    for v in data {
        values.push(convert(v.map_err(|e| bad_data(e.to_string()))?));
    }
    Ok(values)
}

/// The values of a Fortran-order (first index fastest) array in C order (last index fastest).
fn to_c_order(shape: &[u64], fortran: &[f64]) -> Vec<f64> {
    let dims: Vec<usize> = shape.iter().map(|&d| d as usize).collect();
    // Fortran stride of each dimension.
    let mut strides = vec![1usize; dims.len()];
    for k in 1..dims.len() {
        strides[k] = strides[k - 1] * dims[k - 1];
    }
    let mut index = vec![0usize; dims.len()];
    let mut out = Vec::with_capacity(fortran.len());
    for _ in 0..fortran.len() {
        let offset: usize = index.iter().zip(&strides).map(|(i, s)| i * s).sum();
        out.push(fortran[offset]);
        // Advance the C-order multi-index, last dimension fastest.
        for k in (0..dims.len()).rev() {
            index[k] += 1;
            if index[k] < dims[k] {
                break;
            }
            index[k] = 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_order_is_transposed_to_c_order() {
        // A 2 x 3 array [[0, 1, 2], [3, 4, 5]] stored column by column.
        let fortran = [0.0, 3.0, 1.0, 4.0, 2.0, 5.0];
        assert_eq!(
            to_c_order(&[2, 3], &fortran),
            vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
        );
        // 2 x 2 x 2: element (i, j, k) = 4i + 2j + k, at i + 2j + 4k in Fortran order.
        let mut f = vec![0.0; 8];
        for i in 0..2 {
            for j in 0..2 {
                for k in 0..2 {
                    f[i + 2 * j + 4 * k] = (4 * i + 2 * j + k) as f64;
                }
            }
        }
        assert_eq!(
            to_c_order(&[2, 2, 2], &f),
            (0..8).map(f64::from).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_lying_shape_is_refused_before_allocation() {
        assert!(check_shape(&[1 << 40, 1 << 40, 3], 8, 1000).is_err());
        assert!(check_shape(&[10, 10, 3], 8, 2400).is_ok());
        assert!(check_shape(&[10, 10, 3], 8, 2399).is_err());
    }
}
