//! A check of a DICOM file's element lengths before the parser reads it.
//!
//! The DICOM parser reserves what an element's length field claims (up to 4 GiB) before it reads
//! the value, and inflates a deflated data set whole. A crafted file of a few bytes could thus
//! ask for gigabytes. This walk reads only the headers: the transfer syntax must be one of the
//! two uncompressed little-endian ones, and every defined length must fit in the bytes that
//! remain, so that no element can claim more memory than the file holds.

use dicom_core::dictionary::{DataDictionary, DataDictionaryEntry, VirtualVr};
use dicom_core::{Tag, VR};
use dicom_dictionary_std::{StandardDataDictionary, uids};

/// The two transfer syntaxes this reader accepts.
const NATIVE: [&str; 2] = [uids::EXPLICIT_VR_LITTLE_ENDIAN, uids::IMPLICIT_VR_LITTLE_ENDIAN];

const UNDEFINED: u32 = u32::MAX;

fn u16_at(bytes: &[u8], pos: usize) -> Option<u16> {
    bytes.get(pos..pos + 2).map(|b| u16::from_le_bytes([b[0], b[1]]))
}

fn u32_at(bytes: &[u8], pos: usize) -> Option<u32> {
    bytes.get(pos..pos + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Explicit VRs whose length field has 4 bytes (after 2 reserved bytes).
fn long_length(vr: &[u8]) -> bool {
    matches!(vr, b"OB" | b"OD" | b"OF" | b"OL" | b"OV" | b"OW" | b"SQ" | b"SV" | b"UC" | b"UN" | b"UR" | b"UT" | b"UV")
}

/// Whether the standard dictionary says `tag` is a sequence (implicit VR data sets).
fn is_sequence(tag: Tag) -> bool {
    StandardDataDictionary.by_tag(tag).map(|e| matches!(e.vr(), VirtualVr::Exact(VR::SQ))).unwrap_or(false)
}

/// Checks the whole file's bytes (preamble included): a problem is returned as the message the
/// caller attaches to the file's path.
pub fn check_dicom_lengths(bytes: &[u8]) -> std::result::Result<(), String> {
    if bytes.get(128..132) != Some(b"DICM".as_slice()) {
        return Err("not a DICOM file (no `DICM` after the 128-byte preamble)".into());
    }
    let (syntax, data_start) = file_meta(bytes)?;
    if !NATIVE.contains(&syntax.as_str()) {
        // A UID is at most 64 characters of digits and dots; a damaged one is shown escaped
        // and cut, so that no stray bytes reach the terminal.
        let shown: String = syntax.chars().take(64).collect();
        let more = if syntax.chars().count() > 64 { "…" } else { "" };
        return Err(format!(
            "transfer syntax {shown:?}{more} is not uncompressed little endian; decompress first \
             (e.g. `gdcmconv --raw in.dcm out.dcm` or `dcmdjpeg in.dcm out.dcm`)"
        ));
    }
    walk(bytes, data_start, syntax == uids::EXPLICIT_VR_LITTLE_ENDIAN)
}

/// The transfer syntax UID and where the data set starts, from the file meta group (always
/// explicit VR little endian).
fn file_meta(bytes: &[u8]) -> std::result::Result<(String, usize), String> {
    let mut pos = 132;
    let mut syntax = None;
    while u16_at(bytes, pos) == Some(0x0002) {
        let element = u16_at(bytes, pos + 2).ok_or("file meta header cut short")?;
        let vr = bytes.get(pos + 4..pos + 6).ok_or("file meta header cut short")?;
        let (len, header) = if long_length(vr) {
            (u32_at(bytes, pos + 8).ok_or("file meta header cut short")? as usize, 12)
        } else {
            (u16_at(bytes, pos + 6).ok_or("file meta header cut short")? as usize, 8)
        };
        let value = bytes
            .get(pos + header..pos + header + len)
            .ok_or_else(|| format!("file meta element (0002,{element:04X}) claims {len} bytes past the end"))?;
        if element == 0x0010 {
            syntax = Some(String::from_utf8_lossy(value).trim_end_matches(['\0', ' ']).to_string());
        }
        pos += header + len;
    }
    Ok((syntax.ok_or("the file meta header has no Transfer Syntax UID (0002,0010)")?, pos))
}

/// Walks the data set's element headers from `pos`, entering sequences and items, skipping
/// values; fails on a length that runs past the end.
fn walk(bytes: &[u8], mut pos: usize, explicit: bool) -> std::result::Result<(), String> {
    let cut = |pos: usize| format!("an element header at byte {pos} is cut short");
    // Inside encapsulated (undefined-length) pixel data, items hold raw fragments, not elements.
    let mut in_fragments = false;
    while pos < bytes.len() {
        let group = u16_at(bytes, pos).ok_or_else(|| cut(pos))?;
        let element = u16_at(bytes, pos + 2).ok_or_else(|| cut(pos))?;
        let tag = Tag(group, element);
        let (len, header, sequence) = if group == 0xFFFE {
            (u32_at(bytes, pos + 4).ok_or_else(|| cut(pos))?, 8, element == 0xE000 && !in_fragments)
        } else if explicit {
            let vr = bytes.get(pos + 4..pos + 6).ok_or_else(|| cut(pos))?;
            if long_length(vr) {
                (u32_at(bytes, pos + 8).ok_or_else(|| cut(pos))?, 12, vr == b"SQ")
            } else {
                (u16_at(bytes, pos + 6).ok_or_else(|| cut(pos))? as u32, 8, false)
            }
        } else {
            (u32_at(bytes, pos + 4).ok_or_else(|| cut(pos))?, 8, is_sequence(tag))
        };
        pos += header;
        if group == 0xFFFE && element == 0xE0DD {
            in_fragments = false;
        }
        if len == UNDEFINED {
            if tag == Tag(0x7FE0, 0x0010) {
                in_fragments = true;
            }
            continue;
        }
        let remaining = bytes.len() - pos.min(bytes.len());
        if len as usize > remaining {
            return Err(format!(
                "element ({group:04X},{element:04X}) at byte {} claims {len} bytes, but only {remaining} remain",
                pos - header
            ));
        }
        if !sequence {
            pos += len as usize;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Preamble, `DICM` and a meta group naming `syntax`.
    fn header(syntax: &str) -> Vec<u8> {
        let mut b = vec![0u8; 128];
        b.extend_from_slice(b"DICM");
        let mut uid = syntax.as_bytes().to_vec();
        if uid.len() % 2 == 1 {
            uid.push(0);
        }
        b.extend_from_slice(&[0x02, 0x00, 0x10, 0x00, b'U', b'I']);
        b.extend_from_slice(&(uid.len() as u16).to_le_bytes());
        b.extend_from_slice(&uid);
        b
    }

    fn explicit_long(b: &mut Vec<u8>, group: u16, element: u16, vr: &[u8; 2], len: u32) {
        b.extend_from_slice(&group.to_le_bytes());
        b.extend_from_slice(&element.to_le_bytes());
        b.extend_from_slice(vr);
        b.extend_from_slice(&[0, 0]);
        b.extend_from_slice(&len.to_le_bytes());
    }

    #[test]
    fn a_well_formed_data_set_with_a_sequence_passes() {
        let mut b = header(uids::EXPLICIT_VR_LITTLE_ENDIAN);
        b.extend_from_slice(&[0x08, 0x00, 0x60, 0x00, b'C', b'S', 2, 0, b'X', b'A']);
        // A sequence of undefined length holding one item with one element.
        explicit_long(&mut b, 0x0028, 0x6100, b"SQ", UNDEFINED);
        b.extend_from_slice(&[0xFE, 0xFF, 0x00, 0xE0, 10, 0, 0, 0]);
        b.extend_from_slice(&[0x28, 0x00, 0x01, 0x61, b'C', b'S', 2, 0, b'A', b'V']);
        b.extend_from_slice(&[0xFE, 0xFF, 0xDD, 0xE0, 0, 0, 0, 0]);
        explicit_long(&mut b, 0x7FE0, 0x0010, b"OW", 4);
        b.extend_from_slice(&[1, 2, 3, 4]);
        assert_eq!(check_dicom_lengths(&b), Ok(()));
    }

    #[test]
    fn a_length_past_the_end_is_refused_before_anything_is_reserved() {
        let mut b = header(uids::EXPLICIT_VR_LITTLE_ENDIAN);
        explicit_long(&mut b, 0x7FE0, 0x0010, b"OW", 0xFFFF_FFF0);
        b.extend_from_slice(&[0; 16]);
        let err = check_dicom_lengths(&b).unwrap_err();
        assert!(err.contains("(7FE0,0010)") && err.contains("4294967280"), "{err}");
        // Inside a sequence item too, and in an implicit-VR data set.
        let mut b = header(uids::IMPLICIT_VR_LITTLE_ENDIAN);
        b.extend_from_slice(&[0x28, 0x00, 0x00, 0x61, 0xFF, 0xFF, 0xFF, 0xFF]);
        b.extend_from_slice(&[0xFE, 0xFF, 0x00, 0xE0, 0xFF, 0xFF, 0xFF, 0xFF]);
        b.extend_from_slice(&[0x10, 0x00, 0x10, 0x00, 0x00, 0x00, 0x00, 0x80]);
        let err = check_dicom_lengths(&b).unwrap_err();
        assert!(err.contains("(0010,0010)"), "{err}");
    }

    #[test]
    fn compressed_and_deflated_syntaxes_are_refused_before_parsing() {
        let b = header("1.2.840.10008.1.2.1.99");
        assert!(check_dicom_lengths(&b).unwrap_err().contains("1.2.840.10008.1.2.1.99"));
        assert!(check_dicom_lengths(b"not dicom").unwrap_err().contains("DICM"));
        // A damaged UID that swallowed the next elements: shown escaped and cut, no raw bytes.
        let garbage = format!("1.2.840.10008.1.2.1\0\x02\x1b[31m{}", "7".repeat(200));
        let err = check_dicom_lengths(&header(&garbage)).unwrap_err();
        assert!(err.contains("\\0\\u{2}\\u{1b}[31m") && err.contains("…"), "{err}");
        assert!(!err.chars().any(|c| c.is_control()) && err.len() < 300, "{err}");
    }
}
