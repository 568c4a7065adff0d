//! Versioned map files: everything needed to resume a run or relocalise in a known map.
//!
//! Layout (UTF-8):
//! ```text
//! HIPPO_NAV_MAP 2\n
//! length <payload bytes> fnv1a64 <16 hex digits>\n
//! <JSON payload: params, vertices, links, current vertex, odometry since it, frame count, lost flag>
//! ```
//! Loading reads the whole file, then checks, in order, the magic (foreign file), the version, the
//! payload length (truncated file), the FNV-1a 64-bit checksum (corrupted bytes), the JSON, and the map's
//! own consistency (link ends, finite values, params). Only then is a new map built, so a bad file can
//! never leave a half-loaded map. The checksum guards against accidents, not tampering. Files are
//! written to a fresh temporary sibling and renamed over the target ([`crate::files`]), so an interrupted
//! save keeps the previous file intact and a link at either name is never written through.
use crate::error::{MapError, Result};
use crate::experience::ExperienceMap;
use crate::files::write_replacing;
use crate::graph::check_pose;
use std::path::Path;

/// The first word of every map file.
pub const MAGIC: &str = "HIPPO_NAV_MAP";
/// 2: links carry their own information; vertices their odometer reading; closure gate state.
pub const FORMAT_VERSION: u32 = 2;

/// FNV-1a, 64-bit: a simple, well-specified checksum (http://www.isthe.com/chongo/tech/comp/fnv/).
fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        hash ^= u64::from(b);
        hash = hash.wrapping_mul(0x0000_0100_0000_01b3);
    }
    hash
}

/// Serialise a map to the file format.
pub fn to_bytes(map: &ExperienceMap) -> Result<Vec<u8>> {
    let payload = serde_json::to_vec(map)
        .map_err(|e| MapError::Format(format!("cannot encode the map: {e}")))?;
    let mut out = format!(
        "{MAGIC} {FORMAT_VERSION}\nlength {} fnv1a64 {:016x}\n",
        payload.len(),
        fnv1a64(&payload)
    )
    .into_bytes();
    out.extend_from_slice(&payload);
    Ok(out)
}

fn split_line(bytes: &[u8]) -> Option<(&str, &[u8])> {
    let end = bytes.iter().position(|&b| b == b'\n')?;
    let line = std::str::from_utf8(&bytes[..end]).ok()?;
    Some((line, &bytes[end + 1..]))
}

/// Parse and fully validate a map file's bytes.
pub fn from_bytes(bytes: &[u8]) -> Result<ExperienceMap> {
    let foreign = || {
        MapError::Format(format!(
            "it does not start with \"{MAGIC} <version>\"; pass a file written by ExperienceMap.save"
        ))
    };
    let (first, rest) = split_line(bytes).ok_or_else(foreign)?;
    let mut words = first.split(' ');
    if words.next() != Some(MAGIC) {
        return Err(foreign());
    }
    let version: u32 = words
        .next()
        .and_then(|w| w.parse().ok())
        .ok_or_else(foreign)?;
    if version != FORMAT_VERSION {
        return Err(MapError::Format(format!(
            "format version {version}, this build reads version {FORMAT_VERSION}; use the hippo_nav that wrote it"
        )));
    }
    let (header, payload) = split_line(rest).ok_or_else(|| {
        MapError::Format("truncated: the header ends before its second line".into())
    })?;
    let fields: Vec<&str> = header.split(' ').collect();
    let (length, checksum) = match fields.as_slice() {
        ["length", n, "fnv1a64", h] => (n.parse::<usize>().ok(), u64::from_str_radix(h, 16).ok()),
        _ => (None, None),
    };
    let (Some(length), Some(checksum)) = (length, checksum) else {
        return Err(MapError::Format(format!(
            "malformed header line {header:?}"
        )));
    };
    if payload.len() != length {
        return Err(MapError::Format(format!(
            "{}: the header promises {length} payload bytes, the file holds {}",
            if payload.len() < length {
                "truncated"
            } else {
                "trailing bytes"
            },
            payload.len()
        )));
    }
    if fnv1a64(payload) != checksum {
        return Err(MapError::Format(
            "checksum mismatch: the file is corrupted; restore it from a backup".into(),
        ));
    }
    let mut map: ExperienceMap = serde_json::from_slice(payload)
        .map_err(|e| MapError::Format(format!("payload is not a valid map: {e}")))?;
    validate(&map)?;
    map.rebuild_index();
    Ok(map)
}

fn validate(map: &ExperienceMap) -> Result<()> {
    map.params.validate()?;
    let len = map.vertices.len();
    // What `add_vertex` and `add_link` refuse, a file edited with its checksum recomputed must not bring in.
    for v in &map.vertices {
        check_pose("stored vertex pose", &v.world_from_vertex)?;
    }
    for (k, l) in map.links.iter().enumerate() {
        for vertex in [l.from, l.to] {
            if vertex >= len {
                return Err(MapError::UnknownVertex { vertex, len });
            }
        }
        if l.from == l.to {
            return Err(MapError::SelfLink { vertex: l.from });
        }
        check_pose("stored link transform", &l.from_from_to)?;
        crate::graph::check_information(k, &l.information)?;
        if !(l.elapsed_s.is_finite() && l.elapsed_s >= 0.0) {
            return Err(MapError::BadParameter {
                name: "stored link elapsed_s",
                value: l.elapsed_s.to_string(),
                why: "must be finite and >= 0".into(),
            });
        }
    }
    if let Some(vertex) = map.current {
        if vertex >= len {
            return Err(MapError::UnknownVertex { vertex, len });
        }
    }
    if let Some(first) = map.unjoined_from {
        if first > len {
            return Err(MapError::UnknownVertex { vertex: first, len });
        }
    }
    check_pose(
        "stored odometry since the current vertex",
        &map.current_from_agent,
    )?;
    Ok(())
}

/// Save atomically (new temporary file, then rename; see [`crate::files`]).
pub fn save(map: &ExperienceMap, path: &Path) -> Result<()> {
    write_replacing(path, &to_bytes(map)?)
}

pub fn load(path: &Path) -> Result<ExperienceMap> {
    let bytes = std::fs::read(path).map_err(|source| MapError::Io {
        path: path.display().to_string(),
        source,
    })?;
    from_bytes(&bytes)
}

impl ExperienceMap {
    /// Save to a versioned, checksummed file, written atomically (module doc).
    pub fn save(&self, path: &Path) -> Result<()> {
        save(self, path)
    }
    /// Load a saved map; a truncated, corrupted or foreign file is an error and builds nothing.
    pub fn load(path: &Path) -> Result<ExperienceMap> {
        load(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::experience::MapParams;
    use crate::files::test_support::Scratch;

    fn small_map() -> ExperienceMap {
        ExperienceMap::new(MapParams::default()).unwrap()
    }

    /// A link left at the name the old save wrote its temporary to (`map.bin.tmp`) is not followed: the
    /// file it points to keeps its bytes.
    #[cfg(unix)]
    #[test]
    fn a_link_at_the_old_temporary_name_is_not_written_through() {
        let dir = Scratch::new("persist_tmp_link");
        let victim = dir.0.join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        let target = dir.0.join("map.bin");
        std::os::unix::fs::symlink(&victim, dir.0.join("map.bin.tmp")).unwrap();
        save(&small_map(), &target).unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert_eq!(load(&target).unwrap(), small_map());
        assert_eq!(dir.names(), ["map.bin", "map.bin.tmp", "victim"]);
    }

    /// A link at the map's own name is replaced by the map file; what it pointed to is untouched.
    #[cfg(unix)]
    #[test]
    fn a_link_at_the_map_name_is_replaced_by_a_regular_file() {
        let dir = Scratch::new("persist_link");
        let victim = dir.0.join("victim");
        std::fs::write(&victim, b"precious").unwrap();
        let target = dir.0.join("map.bin");
        std::os::unix::fs::symlink(&victim, &target).unwrap();
        save(&small_map(), &target).unwrap();
        assert_eq!(std::fs::read(&victim).unwrap(), b"precious");
        assert!(std::fs::symlink_metadata(&target).unwrap().is_file());
        assert_eq!(load(&target).unwrap(), small_map());
    }

    /// A save that fails after writing (the target is a folder, so the rename fails) leaves no
    /// temporary, and the error names the target.
    #[test]
    fn a_failed_save_leaves_no_temporary() {
        let dir = Scratch::new("persist_fail");
        let target = dir.0.join("map.bin");
        std::fs::create_dir(&target).unwrap();
        let err = save(&small_map(), &target).unwrap_err();
        assert!(
            err.to_string().contains(&target.display().to_string()),
            "{err}"
        );
        assert_eq!(dir.names(), ["map.bin"]);
        let missing = dir.0.join("missing").join("map.bin");
        assert!(save(&small_map(), &missing).is_err());
        assert_eq!(dir.names(), ["map.bin"]);
    }
}
