//! The vocabulary's file format: a short text header, then a little-endian binary payload.
//!
//! ```text
//! hippo_nav vocabulary 1\n
//! length <payload bytes> crc32 <8 hex digits>\n
//! payload: branching u32, levels u32, nodes u32, words u32,
//!          nodes × (centroid 32 bytes, first_child u32, n_children u32, word u32),
//!          words × idf f32
//! ```
//! Loading checks the header, the payload length (a truncated file), the CRC-32 (corrupted bytes) and
//! the tree's structure (every child index inside the node list, every word numbered once, finite idf),
//! so a bad file is one clear error and never a vocabulary that misbehaves later.

use super::vocabulary::{Node, Vocabulary, NO_WORD};
use crate::error::ViewError;

const MAGIC: &str = "hippo_nav vocabulary";
const FORMAT_VERSION: u32 = 1;
const NODE_BYTES: usize = 32 + 4 * 3;

impl Vocabulary {
    /// The vocabulary in its file format.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut payload =
            Vec::with_capacity(16 + self.nodes.len() * NODE_BYTES + 4 * self.idf.len());
        for v in [
            self.branching,
            self.levels,
            self.nodes.len(),
            self.idf.len(),
        ] {
            payload.extend_from_slice(&(v as u32).to_le_bytes());
        }
        for node in &self.nodes {
            payload.extend_from_slice(&node.centroid);
            payload.extend_from_slice(&node.first_child.to_le_bytes());
            payload.extend_from_slice(&node.n_children.to_le_bytes());
            payload.extend_from_slice(&node.word.to_le_bytes());
        }
        for idf in &self.idf {
            payload.extend_from_slice(&idf.to_le_bytes());
        }
        let header = format!(
            "{MAGIC} {FORMAT_VERSION}\nlength {} crc32 {:08x}\n",
            payload.len(),
            crc32fast::hash(&payload)
        );
        let mut bytes = header.into_bytes();
        bytes.extend_from_slice(&payload);
        bytes
    }

    /// Read a vocabulary written by `to_bytes`, checking everything (see the module doc).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ViewError> {
        let bad = |why: String| ViewError::BadVocabulary { why };
        let (first, rest) = split_line(bytes).ok_or_else(|| bad("no header line".into()))?;
        let expected = format!("{MAGIC} {FORMAT_VERSION}");
        if first != expected.as_bytes() {
            let shown = String::from_utf8_lossy(&first[..first.len().min(40)]).into_owned();
            return Err(bad(format!(
                "starts with {shown:?}, expected {expected:?} (not a vocabulary file, or another version)"
            )));
        }
        let (second, payload) = split_line(rest).ok_or_else(|| bad("no length line".into()))?;
        let second =
            std::str::from_utf8(second).map_err(|_| bad("length line is not text".into()))?;
        let fields: Vec<&str> = second.split(' ').collect();
        let (length, crc) = match fields.as_slice() {
            ["length", n, "crc32", c] => (
                n.parse::<usize>()
                    .map_err(|_| bad(format!("length {n:?} is not a number")))?,
                u32::from_str_radix(c, 16).map_err(|_| bad(format!("crc32 {c:?} is not hex")))?,
            ),
            _ => {
                return Err(bad(format!(
                    "second line {second:?} is not `length N crc32 X`"
                )))
            }
        };
        if payload.len() != length {
            return Err(bad(format!(
                "payload is {} bytes, the header says {length} (truncated or appended to)",
                payload.len()
            )));
        }
        if crc32fast::hash(payload) != crc {
            return Err(bad("checksum mismatch (the file is corrupted)".into()));
        }
        let mut reader = Reader { bytes: payload };
        let branching = reader.u32()? as usize;
        let levels = reader.u32()? as usize;
        let n_nodes = reader.u32()? as usize;
        let n_words = reader.u32()? as usize;
        if payload.len() != 16 + n_nodes * NODE_BYTES + 4 * n_words {
            return Err(bad(format!(
                "{n_nodes} nodes and {n_words} words do not fill the {}-byte payload",
                payload.len()
            )));
        }
        let mut nodes = Vec::with_capacity(n_nodes);
        for _ in 0..n_nodes {
            let mut centroid = [0u8; 32];
            centroid.copy_from_slice(reader.take(32)?);
            nodes.push(Node {
                centroid,
                first_child: reader.u32()?,
                n_children: reader.u32()?,
                word: reader.u32()?,
            });
        }
        let idf = (0..n_words)
            .map(|_| reader.u32().map(f32::from_bits))
            .collect::<Result<Vec<f32>, _>>()?;
        let vocabulary = Self {
            branching,
            levels,
            nodes,
            idf,
        };
        vocabulary.check_structure().map_err(bad)?;
        Ok(vocabulary)
    }

    /// Every child inside the node list and after its parent, every word numbered exactly once.
    fn check_structure(&self) -> Result<(), String> {
        if self.nodes.is_empty() {
            return Err("no nodes".into());
        }
        let mut seen = vec![false; self.idf.len()];
        for (i, node) in self.nodes.iter().enumerate() {
            let end = node.first_child as usize + node.n_children as usize;
            if node.n_children > 0 && (node.first_child as usize <= i || end > self.nodes.len()) {
                return Err(format!("node {i} has children outside the node list"));
            }
            if node.word != NO_WORD {
                if node.n_children > 0 {
                    return Err(format!("node {i} is a word with children"));
                }
                let w = node.word as usize;
                if w >= seen.len() || seen[w] {
                    return Err(format!(
                        "node {i} carries word {w}, out of range or repeated"
                    ));
                }
                seen[w] = true;
            } else if node.n_children == 0 && i > 0 {
                return Err(format!("node {i} has neither children nor a word"));
            }
        }
        if seen.iter().any(|s| !s) {
            return Err("some words belong to no node".into());
        }
        if self.idf.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err("an idf weight is negative or not finite".into());
        }
        Ok(())
    }
}

fn split_line(bytes: &[u8]) -> Option<(&[u8], &[u8])> {
    let end = bytes.iter().take(200).position(|&b| b == b'\n')?;
    Some((&bytes[..end], &bytes[end + 1..]))
}

struct Reader<'a> {
    bytes: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], ViewError> {
        if self.bytes.len() < n {
            return Err(ViewError::BadVocabulary {
                why: "payload ends early".into(),
            });
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }

    fn u32(&mut self) -> Result<u32, ViewError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
}
