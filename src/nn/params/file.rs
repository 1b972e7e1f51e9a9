//! Saving and loading a [`ParamStore`]: its slots' parameters and Adam moments, the step counters and the
//! slot layout, in one checksummed binary file written atomically.
//!
//! # File format (version 1, little-endian)
//! ```text
//! magic "MSNPARAM" (8 bytes), version u32 = 1
//! schedule_step u64
//! n_groups u32, then per group: name (u32 byte length + UTF-8), adam step counter u64
//! n_slots u32, then per slot: name (u32 + UTF-8), group index u32, kind tag u32, len u64, kind data:
//!     hash table / zeros: nothing; embedding: rows u64, dim u64;
//!     mlp: n_matrices u32, then fan_in u64, fan_out u64 per matrix
//! data: per slot in order: params[len], m[len], v[len] (f32)
//! checksum u64 over every byte before it (see `Checksum`)
//! ```
//! The file holds slots, not padded arrays, so it loads on a device with another chunk size. Loading checks
//! the checksum before touching the store and refuses a file whose slots (names, order, lengths, kinds,
//! groups) differ from the store's, naming the first slot that differs.

use super::{ParamError, ParamSlot, ParamStore, SlotKind, MAX_NAME_BYTES, PIECE};
use crate::gpu::GpuError;
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: &[u8; 8] = b"MSNPARAM";
const VERSION: u32 = 1;

impl ParamStore {
    /// Saves parameters, Adam moments, step counters and the slot layout to `path`, atomically: a temporary
    /// file in the same folder is written, fsynced and renamed over `path`.
    pub fn save(&self, path: &Path) -> Result<(), ParamError> {
        let atomic_err = |e: crate::util::atomic::WriteError| ParamError::Io {
            path: e.path,
            source: std::io::Error::other(e.reason),
        };
        let (atomic, file) = crate::util::atomic::AtomicFile::create(path).map_err(atomic_err)?;
        let mut w = HashWriter { inner: std::io::BufWriter::with_capacity(1 << 20, file), sum: Checksum::new() };
        self.write_body(&mut w).map_err(|e| match e {
            WriteError::Io(source) => ParamError::Io { path: path.to_owned(), source },
            WriteError::Gpu(g) => ParamError::Gpu(g),
        })?;
        let sum = w.sum.finish();
        let mut inner = w.inner;
        inner.write_all(&sum.to_le_bytes()).map_err(|e| io_err(path, e))?;
        let file = inner.into_inner().map_err(|e| ParamError::Io { path: path.to_owned(), source: e.into_error() })?;
        file.sync_all().map_err(|e| io_err(path, e))?;
        drop(file);
        atomic.commit().map_err(atomic_err)?;
        // Make the rename durable; some filesystems refuse to fsync a directory, which is not an error here.
        if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()).and_then(|d| std::fs::File::open(d).ok()) {
            let _ = d.sync_all();
        }
        Ok(())
    }

    fn write_body(&self, w: &mut HashWriter) -> Result<(), WriteError> {
        w.put(MAGIC)?;
        w.put(&VERSION.to_le_bytes())?;
        w.put(&self.schedule_step.to_le_bytes())?;
        w.put(&(self.groups.len() as u32).to_le_bytes())?;
        for (g, steps) in self.groups.iter().zip(&self.group_steps) {
            w.put_str(&g.name)?;
            w.put(&steps.to_le_bytes())?;
        }
        w.put(&(self.layout.slots.len() as u32).to_le_bytes())?;
        for s in &self.layout.slots {
            w.put(&encode_slot(s))?;
        }
        for s in &self.layout.slots {
            for a in [&self.params, &self.m, &self.v] {
                for (c, r) in self.layout.chunk_ranges(s.range()) {
                    let mut i = r.start;
                    while i < r.end {
                        let e = r.end.min(i + PIECE);
                        let data = self.ctx.download_range(&a.chunks()[c], i, e).map_err(WriteError::Gpu)?;
                        w.put(&f32_to_le(&data))?;
                        i = e;
                    }
                }
            }
        }
        Ok(())
    }

    /// Loads a file written by [`ParamStore::save`] into this store. The checksum, the format and the layout
    /// (slot names, order, lengths, kinds and groups; group names) are all checked before anything is written.
    pub fn load(&mut self, path: &Path) -> Result<(), ParamError> {
        let fmt = |msg: String| ParamError::Format { path: path.to_owned(), msg };
        let io = |source| ParamError::Io { path: path.to_owned(), source };
        let file_len = std::fs::metadata(path).map_err(io)?.len();
        if file_len < 8 + 4 + 8 + 4 + 4 + 8 {
            return Err(fmt(format!("{file_len} bytes is too short")));
        }
        // Pass 1: magic and version (so a foreign file is named as such), then the checksum of everything before
        // the last 8 bytes.
        let mut r = std::fs::File::open(path).map_err(io)?;
        let mut head = [0u8; 12];
        r.read_exact(&mut head).map_err(io)?;
        if &head[..8] != MAGIC {
            return Err(fmt("bad magic".into()));
        }
        let version = u32::from_le_bytes([head[8], head[9], head[10], head[11]]);
        if version != VERSION {
            return Err(fmt(format!("version {version}, this build reads version {VERSION}")));
        }
        let mut sum = Checksum::new();
        sum.update(&head);
        let mut left = file_len - 8 - head.len() as u64;
        let mut buf = vec![0u8; 1 << 20];
        while left > 0 {
            let n = left.min(buf.len() as u64) as usize;
            r.read_exact(&mut buf[..n]).map_err(io)?;
            sum.update(&buf[..n]);
            left -= n as u64;
        }
        let mut tail = [0u8; 8];
        r.read_exact(&mut tail).map_err(io)?;
        if u64::from_le_bytes(tail) != sum.finish() {
            return Err(fmt("checksum mismatch (corrupted or truncated file)".into()));
        }
        // Pass 2: header.
        let mut r = Reader {
            inner: std::io::BufReader::with_capacity(1 << 20, std::fs::File::open(path).map_err(io)?),
            left: file_len - 8,
        };
        let rd = |e: ReadError| match e {
            ReadError::Eof => fmt("truncated".into()),
            ReadError::Io(source) => ParamError::Io { path: path.to_owned(), source },
            ReadError::Bad(msg) => fmt(msg),
        };
        r.bytes(head.len()).map_err(rd)?; // magic and version, checked above
        let schedule_step = r.u64().map_err(rd)?;
        let n_groups = r.u32().map_err(rd)? as usize;
        let mut steps = Vec::new();
        for i in 0..n_groups {
            let name = r.string().map_err(rd)?;
            let s = r.u64().map_err(rd)?;
            match self.groups.get(i) {
                Some(g) if g.name == name => steps.push(s),
                _ => {
                    return Err(fmt(format!(
                        "group {i} is {name:?}, the model's is {:?}",
                        self.groups.get(i).map(|g| &g.name)
                    )))
                }
            }
        }
        if n_groups != self.groups.len() {
            return Err(fmt(format!("{n_groups} groups, the model has {}", self.groups.len())));
        }
        let n_slots = r.u32().map_err(rd)? as usize;
        let mismatch =
            |slot: &str, msg: String| ParamError::LayoutMismatch { path: path.to_owned(), slot: slot.to_owned(), msg };
        for i in 0..n_slots.max(self.layout.slots.len()) {
            let Some(mine) = self.layout.slots.get(i) else {
                let name = r.string().map_err(rd)?;
                return Err(mismatch(&name, "in the file but not in the model".into()));
            };
            if i >= n_slots {
                return Err(mismatch(&mine.name, "in the model but not in the file".into()));
            }
            let theirs = decode_slot(&mut r).map_err(rd)?;
            if theirs != encode_slot(mine) {
                return Err(mismatch(&mine.name, describe_mismatch(mine, &theirs)));
            }
        }
        let data_bytes: u64 = self.layout.slots.iter().map(|s| s.len as u64 * 12).sum();
        if r.left != data_bytes {
            return Err(fmt(format!("{} data bytes, the layout needs {data_bytes}", r.left)));
        }
        // Pass 3: data.
        for s in &self.layout.slots {
            for a in [&self.params, &self.m, &self.v] {
                let mut done = 0;
                while done < s.len {
                    let n = PIECE.min(s.len - done);
                    let bytes = r.bytes(4 * n).map_err(rd)?;
                    let vals: Vec<f32> =
                        bytes.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
                    a.upload(&self.ctx, s.offset + done, &vals)?;
                    done += n;
                }
            }
        }
        self.group_steps = steps;
        self.schedule_step = schedule_step;
        Ok(())
    }
}

fn io_err(path: &Path, source: std::io::Error) -> ParamError {
    ParamError::Io { path: path.to_owned(), source }
}

/// A slot's layout record as stored in the file (everything but its offset).
fn encode_slot(s: &ParamSlot) -> Vec<u8> {
    let mut b = Vec::new();
    b.extend((s.name.len() as u32).to_le_bytes());
    b.extend(s.name.as_bytes());
    b.extend((s.group as u32).to_le_bytes());
    b.extend(s.kind.tag().to_le_bytes());
    b.extend((s.len as u64).to_le_bytes());
    match &s.kind {
        SlotKind::HashTable { .. } | SlotKind::Zeros { .. } => {}
        SlotKind::Embedding { rows, dim } => {
            b.extend((*rows as u64).to_le_bytes());
            b.extend((*dim as u64).to_le_bytes());
        }
        SlotKind::Mlp { matrices } => {
            b.extend((matrices.len() as u32).to_le_bytes());
            for m in matrices {
                b.extend((m.fan_in as u64).to_le_bytes());
                b.extend((m.fan_out as u64).to_le_bytes());
            }
        }
    }
    b
}

/// Reads one slot record and returns its bytes re-encoded (for comparison with [`encode_slot`]).
fn decode_slot(r: &mut Reader) -> Result<Vec<u8>, ReadError> {
    let name = r.string()?;
    let mut b = Vec::new();
    b.extend((name.len() as u32).to_le_bytes());
    b.extend(name.as_bytes());
    b.extend(r.bytes(4 + 4 + 8)?);
    let tag = u32::from_le_bytes([b[b.len() - 12], b[b.len() - 11], b[b.len() - 10], b[b.len() - 9]]);
    match tag {
        0 | 3 => {}
        2 => b.extend(r.bytes(16)?),
        1 => {
            let n = r.u32()?;
            if n > 1 << 16 {
                return Err(ReadError::Bad(format!("slot {name:?}: {n} matrices")));
            }
            b.extend(n.to_le_bytes());
            b.extend(r.bytes(16 * n as usize)?);
        }
        t => return Err(ReadError::Bad(format!("slot {name:?}: unknown kind tag {t}"))),
    }
    Ok(b)
}

fn describe_mismatch(mine: &ParamSlot, theirs: &[u8]) -> String {
    let n = u32::from_le_bytes([theirs[0], theirs[1], theirs[2], theirs[3]]) as usize;
    let name = String::from_utf8_lossy(&theirs[4..4 + n]);
    if name != mine.name {
        return format!("the file has slot {name:?} in its place");
    }
    let rest = &theirs[4 + n..];
    let group = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]);
    let len = u64::from_le_bytes(rest[8..16].try_into().expect("16 bytes read by decode_slot"));
    if len != mine.len as u64 {
        return format!("{len} values in the file, {} in the model", mine.len);
    }
    if group != mine.group as u32 {
        return format!("group {group} in the file, {} in the model", mine.group);
    }
    format!("kind or shape differs (the model's is {:?})", mine.kind)
}

fn f32_to_le(data: &[f32]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        std::borrow::Cow::Borrowed(bytemuck::cast_slice(data))
    } else {
        std::borrow::Cow::Owned(data.iter().flat_map(|v| v.to_le_bytes()).collect())
    }
}

/// The file checksum: 64-bit FNV-1a-style over little-endian 64-bit words (the last word zero-padded), each
/// step `h = (h ^ w) * 0x100000001b3; h ^= h >> 32` (a bijection of h, so any single changed word changes the
/// result), finished with the byte count as one more word.
pub struct Checksum {
    h: u64,
    buf: [u8; 8],
    nbuf: usize,
    len: u64,
}

impl Default for Checksum {
    fn default() -> Self {
        Self::new()
    }
}

impl Checksum {
    pub fn new() -> Self {
        Self { h: 0xcbf2_9ce4_8422_2325, buf: [0; 8], nbuf: 0, len: 0 }
    }

    fn word(&mut self, w: u64) {
        self.h = (self.h ^ w).wrapping_mul(0x0000_0100_0000_01b3);
        self.h ^= self.h >> 32;
    }

    pub fn update(&mut self, mut data: &[u8]) {
        self.len += data.len() as u64;
        if self.nbuf > 0 {
            let take = (8 - self.nbuf).min(data.len());
            self.buf[self.nbuf..self.nbuf + take].copy_from_slice(&data[..take]);
            self.nbuf += take;
            data = &data[take..];
            if self.nbuf < 8 {
                return;
            }
            self.word(u64::from_le_bytes(self.buf));
            self.nbuf = 0;
        }
        let mut words = data.chunks_exact(8);
        for w in &mut words {
            self.word(u64::from_le_bytes(w.try_into().expect("chunks of 8")));
        }
        let rem = words.remainder();
        self.buf[..rem.len()].copy_from_slice(rem);
        self.nbuf = rem.len();
    }

    pub fn finish(mut self) -> u64 {
        if self.nbuf > 0 {
            self.buf[self.nbuf..].fill(0);
            self.word(u64::from_le_bytes(self.buf));
        }
        let len = self.len;
        self.word(len);
        self.h
    }
}

enum WriteError {
    Io(std::io::Error),
    Gpu(GpuError),
}

struct HashWriter {
    inner: std::io::BufWriter<std::fs::File>,
    sum: Checksum,
}

impl HashWriter {
    fn put(&mut self, b: &[u8]) -> Result<(), WriteError> {
        self.sum.update(b);
        self.inner.write_all(b).map_err(WriteError::Io)
    }

    fn put_str(&mut self, s: &str) -> Result<(), WriteError> {
        self.put(&(s.len() as u32).to_le_bytes())?;
        self.put(s.as_bytes())
    }
}

enum ReadError {
    Eof,
    Io(std::io::Error),
    Bad(String),
}

/// Reads the checksummed part of a file, never past it (`left` bytes remain).
struct Reader {
    inner: std::io::BufReader<std::fs::File>,
    left: u64,
}

impl Reader {
    fn bytes(&mut self, n: usize) -> Result<Vec<u8>, ReadError> {
        if n as u64 > self.left {
            return Err(ReadError::Eof);
        }
        let mut b = vec![0u8; n];
        self.inner.read_exact(&mut b).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => ReadError::Eof,
            _ => ReadError::Io(e),
        })?;
        self.left -= n as u64;
        Ok(b)
    }

    fn u32(&mut self) -> Result<u32, ReadError> {
        let b = self.bytes(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self) -> Result<u64, ReadError> {
        let b = self.bytes(8)?;
        Ok(u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }

    fn string(&mut self) -> Result<String, ReadError> {
        let n = self.u32()? as usize;
        if n > MAX_NAME_BYTES {
            return Err(ReadError::Bad(format!("a name of {n} bytes")));
        }
        String::from_utf8(self.bytes(n)?).map_err(|_| ReadError::Bad("a name that is not UTF-8".into()))
    }
}
