//! The STEP (ISO 10303-21) check run before ifc-lite sees a byte: header, known schema,
//! complete DATA section and trailer, well-formed records, every `#n` reference defined.

use super::*;

/// What the STEP check learnt about the file.
#[derive(Debug, Clone)]
pub struct StepSummary {
    pub schema: String,
    pub entities: usize,
}

/// Schemas ifc-lite 28 reads (prefix match on FILE_SCHEMA, upper case).
pub(super) const KNOWN_SCHEMAS: &[&str] = &["IFC2X3", "IFC4X1", "IFC4X2", "IFC4X3", "IFC4"];

pub(super) fn line_of(bytes: &[u8], offset: usize) -> usize {
    1 + bytes[..offset.min(bytes.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}

pub(super) fn find(hay: &[u8], needle: &[u8], from: usize) -> Option<usize> {
    if from >= hay.len() {
        return None;
    }
    hay[from..]
        .windows(needle.len())
        .position(|w| w.eq_ignore_ascii_case(needle))
        .map(|p| p + from)
}

/// Checks that `bytes` is a complete, well-formed IFC STEP file: header, known schema, DATA
/// records `#id=TYPE(...);` with balanced parentheses and closed strings, trailer, no reference
/// to an undefined `#id`. Returns the problem as a sentence naming its line.
pub fn check_step(bytes: &[u8]) -> std::result::Result<StepSummary, String> {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace() && *b != 0xEF && *b != 0xBB && *b != 0xBF)
        .ok_or("empty file")?;
    let body = &bytes[start..];
    if !body.starts_with(b"ISO-10303-21;") {
        return Err(if body.starts_with(b"PK") {
            "looks like a zip archive (.ifczip?): unzip it first".into()
        } else if body.starts_with(b"{") {
            "looks like JSON (IFC5/ifcJSON?), which is not supported: expected an IFC STEP file"
                .into()
        } else if body.starts_with(b"<") {
            "looks like XML (ifcXML?), which is not supported: expected an IFC STEP file".into()
        } else {
            "not an IFC file: it does not start with the STEP header 'ISO-10303-21;'".into()
        });
    }
    let hdr_end =
        find(bytes, b"ENDSEC;", start).ok_or("truncated or malformed: no end of HEADER section")?;
    let header = &bytes[start..hdr_end];
    let fs = find(header, b"FILE_SCHEMA", 0).ok_or("malformed header: no FILE_SCHEMA")?;
    let q1 = header[fs..]
        .iter()
        .position(|&b| b == b'\'')
        .map(|p| p + fs)
        .ok_or("malformed FILE_SCHEMA")?;
    let q2 = header[q1 + 1..]
        .iter()
        .position(|&b| b == b'\'')
        .map(|p| p + q1 + 1)
        .ok_or("malformed FILE_SCHEMA")?;
    let schema = String::from_utf8_lossy(&header[q1 + 1..q2])
        .trim()
        .to_string();
    let up = schema.to_ascii_uppercase();
    if !KNOWN_SCHEMAS.iter().any(|k| up.starts_with(k)) {
        return Err(format!(
            "unknown IFC schema '{schema}' (bimtiles reads IFC2X3, IFC4, IFC4X1, IFC4X2 and IFC4X3)"
        ));
    }
    let data = find(bytes, b"DATA;", hdr_end).ok_or("truncated: no DATA section")?;
    let mut i = data + 5;
    let n = bytes.len();
    // Pass 1: records and definitions; references go to a list checked afterwards.
    let mut defined: Vec<u64> = Vec::new(); // bitset by id
    let mut defined_big: HashSet<u64> = HashSet::new();
    let mut refs: Vec<(u32, u32)> = Vec::new(); // (ref id, offset / 16) compact: ids only to check
    let mut ref_offsets_first_bad: Option<usize> = None;
    let mut entities = 0usize;
    let mut ended = false;
    let set_def = |id: u64, defined: &mut Vec<u64>, big: &mut HashSet<u64>| {
        if id < (1 << 31) {
            let w = (id / 64) as usize;
            if w >= defined.len() {
                defined.resize(w + 1, 0);
            }
            defined[w] |= 1 << (id % 64);
        } else {
            big.insert(id);
        }
    };
    let skip_ws_comments = |mut i: usize| -> std::result::Result<usize, String> {
        loop {
            while i < n && bytes[i].is_ascii_whitespace() {
                i += 1;
            }
            if i + 1 < n && bytes[i] == b'/' && bytes[i + 1] == b'*' {
                match find(bytes, b"*/", i + 2) {
                    Some(e) => i = e + 2,
                    None => {
                        return Err(format!(
                            "truncated: unclosed comment at line {}",
                            line_of(bytes, i)
                        ))
                    }
                }
            } else {
                return Ok(i);
            }
        }
    };
    while i < n {
        i = skip_ws_comments(i)?;
        if i >= n {
            break;
        }
        if bytes[i..].len() >= 7 && bytes[i..i + 7].eq_ignore_ascii_case(b"ENDSEC;") {
            ended = true;
            i += 7;
            break;
        }
        let rec_start = i;
        if bytes[i] != b'#' {
            return Err(format!(
                "malformed record at line {}: expected '#id=' or ENDSEC;",
                line_of(bytes, i)
            ));
        }
        i += 1;
        let ds = i;
        let mut id: u64 = 0;
        while i < n && bytes[i].is_ascii_digit() {
            id = id
                .saturating_mul(10)
                .saturating_add((bytes[i] - b'0') as u64);
            i += 1;
        }
        if i == ds {
            return Err(format!(
                "malformed record at line {}: '#' without a number",
                line_of(bytes, rec_start)
            ));
        }
        i = skip_ws_comments(i)?;
        if i >= n || bytes[i] != b'=' {
            return Err(format!(
                "malformed record #{id} at line {}: expected '='",
                line_of(bytes, rec_start)
            ));
        }
        i += 1;
        // Body up to the ';' at depth 0 outside strings.
        let mut depth: i64 = 0;
        let mut in_str = false;
        let mut saw_paren = false;
        let mut closed = false;
        while i < n {
            let b = bytes[i];
            if in_str {
                if b == b'\'' {
                    in_str = false;
                }
                i += 1;
                continue;
            }
            match b {
                b'\'' => in_str = true,
                b'(' => {
                    depth += 1;
                    saw_paren = true;
                }
                b')' => {
                    depth -= 1;
                    if depth < 0 {
                        return Err(format!(
                            "malformed record #{id} at line {}: unbalanced ')'",
                            line_of(bytes, rec_start)
                        ));
                    }
                }
                b'/' if i + 1 < n && bytes[i + 1] == b'*' => match find(bytes, b"*/", i + 2) {
                    Some(e) => {
                        i = e + 2;
                        continue;
                    }
                    None => {
                        return Err(format!(
                            "truncated: unclosed comment at line {}",
                            line_of(bytes, i)
                        ))
                    }
                },
                b'#' => {
                    let mut j = i + 1;
                    let mut r: u64 = 0;
                    while j < n && bytes[j].is_ascii_digit() {
                        r = r
                            .saturating_mul(10)
                            .saturating_add((bytes[j] - b'0') as u64);
                        j += 1;
                    }
                    if j > i + 1 {
                        if r <= u32::MAX as u64 {
                            refs.push((r as u32, id.min(u32::MAX as u64) as u32));
                        } else if ref_offsets_first_bad.is_none() {
                            ref_offsets_first_bad = Some(rec_start);
                        }
                    }
                    i = j;
                    continue;
                }
                b';' => {
                    if depth != 0 {
                        return Err(format!(
                            "malformed record #{id} at line {}: unbalanced parentheses",
                            line_of(bytes, rec_start)
                        ));
                    }
                    closed = true;
                    i += 1;
                    break;
                }
                _ => {}
            }
            i += 1;
        }
        if !closed {
            return Err(format!(
                "truncated: record #{id} at line {} is not terminated (the file ends inside it)",
                line_of(bytes, rec_start)
            ));
        }
        if !saw_paren || depth != 0 {
            return Err(format!(
                "malformed record #{id} at line {}: no attribute list",
                line_of(bytes, rec_start)
            ));
        }
        set_def(id, &mut defined, &mut defined_big);
        entities += 1;
    }
    if !ended {
        return Err("truncated: the DATA section has no ENDSEC;".into());
    }
    if find(bytes, b"END-ISO-10303-21", i).is_none() {
        return Err("truncated: no 'END-ISO-10303-21;' trailer".into());
    }
    if entities == 0 {
        return Err("the DATA section holds no entities".into());
    }
    if let Some(off) = ref_offsets_first_bad {
        return Err(format!(
            "malformed record at line {}: reference number out of range",
            line_of(bytes, off)
        ));
    }
    let is_def = |r: u32| -> bool {
        let r = r as u64;
        let w = (r / 64) as usize;
        (w < defined.len() && defined[w] & (1 << (r % 64)) != 0) || defined_big.contains(&r)
    };
    let mut bad = refs.iter().filter(|(r, _)| !is_def(*r));
    if let Some(&(r, from)) = bad.next() {
        let more = bad.count();
        return Err(format!(
            "broken reference: #{from} refers to #{r}, which is not defined{}",
            if more > 0 {
                format!(" ({more} more broken references)")
            } else {
                String::new()
            }
        ));
    }
    Ok(StepSummary { schema, entities })
}

// ------------------------------------------------------------------------------------------------
// Scene assembly (ours, on plain data)
// ------------------------------------------------------------------------------------------------
