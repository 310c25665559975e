//! A small, safe pickle interpreter: enough of protocols 2–5 to read the
//! official AIST++ annotation files (dicts of numpy arrays) and similar
//! numpy pickles. It never executes code: the only "globals" it understands
//! are numpy's array/dtype/scalar reconstructors and `_codecs.encode`; any
//! other global is an error naming it.
//!
//! Every length comes from bytes already in memory, so no allocation is
//! sized by an untrusted header beyond the input's own size.

use super::npy::NdArray;
use std::collections::HashMap;

/// A decoded pickle value.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    Bytes(Vec<u8>),
    Tuple(Vec<Value>),
    List(Vec<Value>),
    Dict(Vec<(Value, Value)>),
    Array(NdArray),
    /// A numpy dtype under construction: its descr (`"f4"`) and byte order.
    Dtype {
        descr: String,
        order: char,
    },
    /// A callable named by GLOBAL / STACK_GLOBAL.
    Global {
        module: String,
        name: String,
    },
    Mark,
}

impl Value {
    pub fn as_dict(&self) -> Option<&[(Value, Value)]> {
        match self {
            Value::Dict(d) => Some(d),
            _ => None,
        }
    }
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Value::Str(s) => Some(s),
            _ => None,
        }
    }
    fn kind(&self) -> &'static str {
        match self {
            Value::None => "None",
            Value::Bool(_) => "bool",
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Str(_) => "str",
            Value::Bytes(_) => "bytes",
            Value::Tuple(_) => "tuple",
            Value::List(_) => "list",
            Value::Dict(_) => "dict",
            Value::Array(_) => "ndarray",
            Value::Dtype { .. } => "dtype",
            Value::Global { .. } => "global",
            Value::Mark => "mark",
        }
    }
}

/// Look a string key up in a pickled dict.
pub fn dict_get<'a>(d: &'a [(Value, Value)], key: &str) -> Option<&'a Value> {
    d.iter()
        .find(|(k, _)| k.as_str() == Some(key))
        .map(|(_, v)| v)
}

/// Deepest stack (and so deepest nesting) accepted; AIST++ files need < 20.
const MAX_STACK: usize = 4096;
const MAX_MEMO: usize = 1_000_000;

struct Vm<'a> {
    data: &'a [u8],
    /// Values copied by DUP / memo gets so far, weighed by [`weight`]: a
    /// pickle that copies a container into itself grows exponentially, so
    /// copies are capped at a multiple of the input size.
    copied: usize,
    pos: usize,
    stack: Vec<Value>,
    memo: HashMap<u32, Value>,
}

/// Decode a pickle. Errors are plain reasons (the caller adds the file).
pub fn load(data: &[u8]) -> Result<Value, String> {
    let mut vm = Vm {
        data,
        copied: 0,
        pos: 0,
        stack: Vec::new(),
        memo: HashMap::new(),
    };
    vm.run()
}

impl<'a> Vm<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        if n > self.data.len() - self.pos {
            return Err(format!(
                "truncated: needs {n} bytes at offset {}, only {} left",
                self.pos,
                self.data.len() - self.pos
            ));
        }
        let s = &self.data[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, String> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn u64(&mut self) -> Result<u64, String> {
        let b = self.take(8)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
    fn line(&mut self) -> Result<&'a str, String> {
        let rest = &self.data[self.pos..];
        let end = rest
            .iter()
            .position(|&b| b == b'\n')
            .ok_or("truncated: unterminated text line")?;
        self.pos += end + 1;
        std::str::from_utf8(&rest[..end]).map_err(|_| "text line is not UTF-8".to_string())
    }
    fn push(&mut self, v: Value) -> Result<(), String> {
        if self.stack.len() >= MAX_STACK {
            return Err(format!("stack deeper than {MAX_STACK}"));
        }
        self.stack.push(v);
        Ok(())
    }
    fn pop(&mut self) -> Result<Value, String> {
        self.stack
            .pop()
            .ok_or_else(|| "stack underflow".to_string())
    }
    fn top(&mut self) -> Result<&mut Value, String> {
        self.stack
            .last_mut()
            .ok_or_else(|| "stack underflow".to_string())
    }
    fn pop_mark(&mut self) -> Result<Vec<Value>, String> {
        let i = self
            .stack
            .iter()
            .rposition(|v| matches!(v, Value::Mark))
            .ok_or("no MARK on the stack")?;
        let items = self.stack.split_off(i + 1);
        self.stack.pop();
        Ok(items)
    }
    fn memo_put(&mut self, idx: u32) -> Result<(), String> {
        if self.memo.len() >= MAX_MEMO {
            return Err(format!("memo larger than {MAX_MEMO}"));
        }
        let v = self
            .stack
            .last()
            .ok_or("MEMOIZE on an empty stack")?
            .clone();
        self.memo.insert(idx, v);
        Ok(())
    }
    fn memo_get(&mut self, idx: u32) -> Result<(), String> {
        let v = self
            .memo
            .get(&idx)
            .ok_or(format!("memo key {idx} never stored"))?;
        let w = weight(v, self.budget());
        let v = v.clone();
        self.charge(w)?;
        self.push(v)
    }
    fn budget(&self) -> usize {
        64 * self.data.len() + (1 << 20)
    }
    fn charge(&mut self, w: usize) -> Result<(), String> {
        self.copied = self.copied.saturating_add(w);
        if self.copied > self.budget() {
            return Err(
                "pickle copies more data than it holds (a recursive or exploding structure)".into(),
            );
        }
        Ok(())
    }
    fn utf8(b: &[u8]) -> Result<String, String> {
        String::from_utf8(b.to_vec()).map_err(|_| "string is not UTF-8".to_string())
    }

    fn run(&mut self) -> Result<Value, String> {
        loop {
            let at = self.pos;
            let op = self
                .u8()
                .map_err(|_| "truncated: no STOP opcode".to_string())?;
            match op {
                0x80 => {
                    let proto = self.u8()?;
                    if proto > 5 {
                        return Err(format!("pickle protocol {proto} is not supported"));
                    }
                }
                0x95 => {
                    self.u64()?;
                }
                b'.' => return self.pop(),
                b'(' => self.push(Value::Mark)?,
                b'0' => {
                    self.pop()?;
                }
                b'1' => {
                    self.pop_mark()?;
                }
                b'2' => {
                    let budget = self.budget();
                    let w = weight(self.top()?, budget);
                    self.charge(w)?;
                    let v = self.top()?.clone();
                    self.push(v)?;
                }
                b'}' => self.push(Value::Dict(Vec::new()))?,
                b']' => self.push(Value::List(Vec::new()))?,
                b')' => self.push(Value::Tuple(Vec::new()))?,
                b'd' => {
                    let items = self.pop_mark()?;
                    self.push(Value::Dict(pairs(items)?))?;
                }
                b'l' => {
                    let items = self.pop_mark()?;
                    self.push(Value::List(items))?;
                }
                b't' => {
                    let items = self.pop_mark()?;
                    self.push(Value::Tuple(items))?;
                }
                0x85 => {
                    let a = self.pop()?;
                    self.push(Value::Tuple(vec![a]))?;
                }
                0x86 => {
                    let b = self.pop()?;
                    let a = self.pop()?;
                    self.push(Value::Tuple(vec![a, b]))?;
                }
                0x87 => {
                    let c = self.pop()?;
                    let b = self.pop()?;
                    let a = self.pop()?;
                    self.push(Value::Tuple(vec![a, b, c]))?;
                }
                b's' => {
                    let v = self.pop()?;
                    let k = self.pop()?;
                    match self.top()? {
                        Value::Dict(d) => d.push((k, v)),
                        other => return Err(format!("SETITEM on a {}", other.kind())),
                    }
                }
                b'u' => {
                    let items = self.pop_mark()?;
                    let kv = pairs(items)?;
                    match self.top()? {
                        Value::Dict(d) => d.extend(kv),
                        other => return Err(format!("SETITEMS on a {}", other.kind())),
                    }
                }
                b'a' => {
                    let v = self.pop()?;
                    match self.top()? {
                        Value::List(l) => l.push(v),
                        other => return Err(format!("APPEND on a {}", other.kind())),
                    }
                }
                b'e' => {
                    let items = self.pop_mark()?;
                    match self.top()? {
                        Value::List(l) => l.extend(items),
                        other => return Err(format!("APPENDS on a {}", other.kind())),
                    }
                }
                0x94 => {
                    let idx = self.memo.len() as u32;
                    self.memo_put(idx)?;
                }
                b'q' => {
                    let i = self.u8()? as u32;
                    self.memo_put(i)?;
                }
                b'r' => {
                    let i = self.u32()?;
                    self.memo_put(i)?;
                }
                b'h' => {
                    let i = self.u8()? as u32;
                    self.memo_get(i)?;
                }
                b'j' => {
                    let i = self.u32()?;
                    self.memo_get(i)?;
                }
                b'J' => {
                    let b = self.take(4)?;
                    self.push(Value::Int(
                        i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as i64
                    ))?;
                }
                b'K' => {
                    let v = self.u8()?;
                    self.push(Value::Int(v as i64))?;
                }
                b'M' => {
                    let v = self.u16()?;
                    self.push(Value::Int(v as i64))?;
                }
                0x8a => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?;
                    if n > 8 {
                        return Err(format!("LONG1 of {n} bytes does not fit in 64 bits"));
                    }
                    let mut buf = if b.last().is_some_and(|&x| x & 0x80 != 0) {
                        [0xffu8; 8]
                    } else {
                        [0u8; 8]
                    };
                    buf[..n].copy_from_slice(b);
                    self.push(Value::Int(i64::from_le_bytes(buf)))?;
                }
                b'N' => self.push(Value::None)?,
                0x88 => self.push(Value::Bool(true))?,
                0x89 => self.push(Value::Bool(false))?,
                b'G' => {
                    let b = self.take(8)?;
                    self.push(Value::Float(f64::from_be_bytes(
                        b.try_into().expect("8 bytes"),
                    )))?;
                }
                0x8c => {
                    let n = self.u8()? as usize;
                    let s = Self::utf8(self.take(n)?)?;
                    self.push(Value::Str(s))?;
                }
                b'X' => {
                    let n = self.u32()? as usize;
                    let s = Self::utf8(self.take(n)?)?;
                    self.push(Value::Str(s))?;
                }
                0x8d => {
                    let n = usize::try_from(self.u64()?).map_err(|_| "length overflow")?;
                    let s = Self::utf8(self.take(n)?)?;
                    self.push(Value::Str(s))?;
                }
                b'C' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                b'B' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                0x8e | 0x96 => {
                    let n = usize::try_from(self.u64()?).map_err(|_| "length overflow")?;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                // Python 2 byte strings (numpy pickles written by Python 2).
                b'U' => {
                    let n = self.u8()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                b'T' => {
                    let n = self.u32()? as usize;
                    let b = self.take(n)?.to_vec();
                    self.push(Value::Bytes(b))?;
                }
                b'c' => {
                    let module = self.line()?.to_string();
                    let name = self.line()?.to_string();
                    self.push(Value::Global { module, name })?;
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    match (module, name) {
                        (Value::Str(module), Value::Str(name)) => {
                            self.push(Value::Global { module, name })?
                        }
                        _ => return Err("STACK_GLOBAL needs two strings".into()),
                    }
                }
                b'R' | 0x81 => {
                    let args = self.pop()?;
                    let func = self.pop()?;
                    let v = reduce(func, args)?;
                    self.push(v)?;
                }
                b'b' => {
                    let state = self.pop()?;
                    let obj = self.pop()?;
                    let v = build(obj, state)?;
                    self.push(v)?;
                }
                other => {
                    return Err(format!(
                        "unsupported pickle opcode 0x{other:02x} at offset {at}"
                    ));
                }
            }
        }
    }
}

/// Roughly the bytes a value holds, counting at most `cap`.
fn weight(v: &Value, cap: usize) -> usize {
    let mut total = 0usize;
    let mut todo = vec![v];
    while let Some(v) = todo.pop() {
        total += 16;
        match v {
            Value::Str(s) => total += s.len(),
            Value::Bytes(b) => total += b.len(),
            Value::Array(a) => total += 8 * a.data.len(),
            Value::Tuple(t) | Value::List(t) => todo.extend(t.iter()),
            Value::Dict(d) => todo.extend(d.iter().flat_map(|(k, v)| [k, v])),
            _ => {}
        }
        if total > cap {
            break;
        }
    }
    total
}

fn pairs(items: Vec<Value>) -> Result<Vec<(Value, Value)>, String> {
    if items.len() % 2 != 0 {
        return Err("odd number of items for a dict".into());
    }
    let mut out = Vec::with_capacity(items.len() / 2);
    let mut it = items.into_iter();
    while let (Some(k), Some(v)) = (it.next(), it.next()) {
        out.push((k, v));
    }
    Ok(out)
}

fn is_numpy_multiarray(module: &str) -> bool {
    matches!(module, "numpy.core.multiarray" | "numpy._core.multiarray")
}

fn reduce(func: Value, args: Value) -> Result<Value, String> {
    let Value::Global { module, name } = func else {
        return Err(format!("REDUCE on a {}, not a callable", func.kind()));
    };
    let args = match args {
        Value::Tuple(a) => a,
        other => {
            return Err(format!(
                "REDUCE arguments are a {}, not a tuple",
                other.kind()
            ))
        }
    };
    match (module.as_str(), name.as_str()) {
        (m, "_reconstruct") if is_numpy_multiarray(m) => Ok(Value::Array(NdArray::empty())),
        ("numpy", "dtype") => match args.first() {
            Some(Value::Str(d)) => Ok(Value::Dtype {
                descr: d.clone(),
                order: '=',
            }),
            _ => Err("numpy.dtype needs a descr string".into()),
        },
        (m, "scalar") if is_numpy_multiarray(m) => {
            let (Some(Value::Dtype { descr, order }), Some(Value::Bytes(b))) =
                (args.first(), args.get(1))
            else {
                return Err("numpy scalar needs (dtype, bytes)".into());
            };
            let a = NdArray::from_raw(&dtype_string(descr, *order), vec![], b, false)?;
            Ok(Value::Float(a.data[0]))
        }
        ("_codecs", "encode") => match args.first() {
            // Python 3 pickles of bytes at protocol < 3: latin-1 code points.
            Some(Value::Str(s)) => Ok(Value::Bytes(
                s.chars()
                    .map(|c| {
                        u8::try_from(c as u32)
                            .map_err(|_| "non-latin-1 char in encoded bytes".to_string())
                    })
                    .collect::<Result<_, _>>()?,
            )),
            _ => Err("_codecs.encode needs a string".into()),
        },
        _ => Err(format!(
            "refusing to call {module}.{name}: only numpy arrays and plain containers are read"
        )),
    }
}

fn dtype_string(descr: &str, order: char) -> String {
    let order = match order {
        '|' | '=' => '<',
        o => o,
    };
    if descr.starts_with(['<', '>', '|', '=']) {
        descr.to_string()
    } else {
        format!("{order}{descr}")
    }
}

fn build(obj: Value, state: Value) -> Result<Value, String> {
    match obj {
        Value::Dtype { descr, .. } => {
            // numpy dtype state: (version, byteorder, subdescr, names, fields, ...)
            let order = match &state {
                Value::Tuple(t) => match t.get(1) {
                    Some(Value::Str(s)) => s.chars().next().unwrap_or('='),
                    _ => '=',
                },
                _ => '=',
            };
            Ok(Value::Dtype { descr, order })
        }
        Value::Array(_) => {
            // ndarray state: (version, shape, dtype, is_fortran, rawdata)
            let Value::Tuple(t) = state else {
                return Err("ndarray state is not a tuple".into());
            };
            if t.len() != 5 {
                return Err(format!("ndarray state has {} items, expected 5", t.len()));
            }
            let shape = match &t[1] {
                Value::Tuple(s) => s
                    .iter()
                    .map(|v| match v {
                        Value::Int(i) if *i >= 0 => Ok(*i as usize),
                        _ => Err("ndarray shape holds a non-integer".to_string()),
                    })
                    .collect::<Result<Vec<_>, _>>()?,
                _ => return Err("ndarray shape is not a tuple".into()),
            };
            let Value::Dtype { descr, order } = &t[2] else {
                return Err("ndarray dtype is missing".into());
            };
            let fortran = matches!(t[3], Value::Bool(true) | Value::Int(1));
            let Value::Bytes(raw) = &t[4] else {
                return Err(format!(
                    "ndarray data is a {} (object arrays are not read)",
                    t[4].kind()
                ));
            };
            Ok(Value::Array(NdArray::from_raw(
                &dtype_string(descr, *order),
                shape,
                raw,
                fortran,
            )?))
        }
        other => Err(format!("BUILD on a {} is not supported", other.kind())),
    }
}

#[cfg(test)]
mod tests;
