//! numpy arrays: the `.npy` format (versions 1–3) and a plain n-d array type
//! shared with the pickle reader. Values are widened to `f64`.

/// A numeric n-d array in C order, values widened to f64.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct NdArray {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

impl NdArray {
    pub fn empty() -> Self {
        NdArray::default()
    }

    /// Decode raw bytes of dtype `descr` (`<f4`, `>f8`, `|u1`, ...) with the
    /// given shape. The byte count must match exactly.
    pub fn from_raw(
        descr: &str,
        shape: Vec<usize>,
        raw: &[u8],
        fortran: bool,
    ) -> Result<Self, String> {
        if !descr.is_ascii() || descr.is_empty() {
            return Err(format!("dtype '{descr}' is not understood"));
        }
        let (order, kind) = descr.split_at(1);
        let big = match order {
            "<" | "|" | "=" => false,
            ">" => true,
            _ => return Err(format!("dtype '{descr}' has no byte-order mark")),
        };
        let width: usize = kind
            .get(1..)
            .and_then(|w| w.parse().ok())
            .ok_or(format!("dtype '{descr}' is not understood"))?;
        let code = kind.chars().next().unwrap_or('?');
        let supported = matches!(
            (code, width),
            ('f', 4) | ('f', 8) | ('f', 2) | ('i', 1 | 2 | 4 | 8) | ('u', 1 | 2 | 4 | 8) | ('b', 1)
        );
        if !supported {
            return Err(format!("dtype '{descr}' is not a supported numeric type"));
        }
        let count = shape
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d))
            .ok_or("array shape overflows")?;
        let need = count.checked_mul(width).ok_or("array size overflows")?;
        if need != raw.len() {
            return Err(format!(
                "array of shape {shape:?} and dtype {descr} needs {need} bytes, found {}",
                raw.len()
            ));
        }
        let mut data = Vec::with_capacity(count);
        for chunk in raw.chunks_exact(width) {
            let mut b = [0u8; 8];
            b[..width].copy_from_slice(chunk);
            if big {
                b[..width].reverse();
            }
            let v = match (code, width) {
                ('f', 2) => half_to_f64(u16::from_le_bytes([b[0], b[1]])),
                ('f', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                ('f', 8) => f64::from_le_bytes(b),
                ('i', 1) => b[0] as i8 as f64,
                ('i', 2) => i16::from_le_bytes([b[0], b[1]]) as f64,
                ('i', 4) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
                ('i', 8) => i64::from_le_bytes(b) as f64,
                ('u', 8) => u64::from_le_bytes(b) as f64,
                ('u', _) | ('b', _) => u64::from_le_bytes(b) as f64,
                _ => unreachable!("checked above"),
            };
            data.push(v);
        }
        let mut a = NdArray { shape, data };
        if fortran && a.shape.len() > 1 {
            a = a.fortran_to_c();
        }
        Ok(a)
    }

    fn fortran_to_c(self) -> NdArray {
        let shape = self.shape.clone();
        let n = self.data.len();
        let mut out = vec![0.0; n];
        // Index i in C order <-> multi-index <-> position in Fortran order.
        for (i, slot) in out.iter_mut().enumerate() {
            let mut rem = i;
            let mut idx = vec![0usize; shape.len()];
            for d in (0..shape.len()).rev() {
                idx[d] = rem % shape[d];
                rem /= shape[d];
            }
            let mut f = 0;
            let mut stride = 1;
            for d in 0..shape.len() {
                f += idx[d] * stride;
                stride *= shape[d];
            }
            *slot = self.data[f];
        }
        NdArray { shape, data: out }
    }

    /// `(rows, cols)` of a 2-D array (a 1-D array is one row).
    pub fn dims2(&self) -> Option<(usize, usize)> {
        match self.shape.as_slice() {
            [r, c] => Some((*r, *c)),
            [c] => Some((1, *c)),
            _ => None,
        }
    }

    /// The single value of a 0-d or one-element array.
    pub fn scalar(&self) -> Option<f64> {
        (self.data.len() == 1).then(|| self.data[0])
    }

    /// Encode as `.npy` version 1.0, little-endian f8 or f4.
    pub fn to_npy(&self, f32_data: bool) -> Vec<u8> {
        let mut out = npy_header(&self.shape, f32_data);
        for &v in &self.data {
            if f32_data {
                out.extend_from_slice(&(v as f32).to_le_bytes());
            } else {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        out
    }
}

/// The `.npy` (version 1.0) header of a C-ordered array of this shape,
/// little-endian f32 (`<f4`) or f64 (`<f8`); the data follows it.
pub fn npy_header(shape: &[usize], f32_data: bool) -> Vec<u8> {
    let shape = match shape.len() {
        0 => "()".to_string(),
        1 => format!("({},)", shape[0]),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let descr = if f32_data { "<f4" } else { "<f8" };
    let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
    let total = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - total % 64) % 64));
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out
}

fn half_to_f64(h: u16) -> f64 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let frac = (h & 0x3ff) as f64;
    match exp {
        0 => sign * frac * 2f64.powi(-24),
        31 => {
            if frac == 0.0 {
                sign * f64::INFINITY
            } else {
                f64::NAN
            }
        }
        e => sign * (1.0 + frac / 1024.0) * 2f64.powi(e - 15),
    }
}

/// Parse a `.npy` file's bytes.
pub fn parse_npy(bytes: &[u8]) -> Result<NdArray, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy array (bad magic)".into());
    }
    let major = bytes[6];
    let (hlen, start): (usize, usize) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated .npy header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(format!(".npy version {v} is not supported")),
    };
    let end = start
        .checked_add(hlen)
        .filter(|&e| e <= bytes.len())
        .ok_or("truncated .npy header")?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| ".npy header is not text")?;
    let descr = header_str(header, "descr").ok_or(".npy header has no 'descr'")?;
    let fortran = header_field(header, "fortran_order")
        .map(|v| v.starts_with("True"))
        .unwrap_or(false);
    let shape_txt = header_field(header, "shape").ok_or(".npy header has no 'shape'")?;
    let close = shape_txt.find(')').ok_or(".npy shape is not a tuple")?;
    let inner = shape_txt.get(1..close).ok_or(".npy shape is not a tuple")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!(".npy shape entry '{s}' is not a size"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    NdArray::from_raw(&descr, shape, &bytes[end..], fortran)
}

fn header_field<'h>(header: &'h str, key: &str) -> Option<&'h str> {
    let pat = format!("'{key}':");
    let i = header.find(&pat)? + pat.len();
    Some(header[i..].trim_start())
}

fn header_str(header: &str, key: &str) -> Option<String> {
    let v = header_field(header, key)?;
    let q = v.chars().next()?;
    if q != '\'' && q != '"' {
        return None;
    }
    let rest = &v[1..];
    Some(rest[..rest.find(q)?].to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_and_fortran_order() {
        let a = NdArray {
            shape: vec![2, 3],
            data: vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        };
        assert_eq!(parse_npy(&a.to_npy(false)).unwrap(), a);
        // The same matrix stored column-major.
        let raw: Vec<u8> = [1.0f64, 4.0, 2.0, 5.0, 3.0, 6.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = NdArray::from_raw("<f8", vec![2, 3], &raw, true).unwrap();
        assert_eq!(f, a);
    }

    #[test]
    fn bad_npy_errors() {
        assert!(parse_npy(b"hello").is_err());
        let mut b = NdArray {
            shape: vec![4],
            data: vec![0.0; 4],
        }
        .to_npy(true);
        b.truncate(b.len() - 1);
        assert!(parse_npy(&b).unwrap_err().contains("needs 16 bytes"));
        assert!(NdArray::from_raw("<c16", vec![1], &[0; 16], false).is_err());
        assert!(NdArray::from_raw("<f8", vec![usize::MAX, 2], &[], false).is_err());
    }
}
