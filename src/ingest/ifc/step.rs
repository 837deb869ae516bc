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

/// Why a file is not a complete, well-formed IFC STEP file. Problems inside the DATA section name
/// their line (1-based) and, when it was read, the record's `#id`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StepError {
    #[error("empty file")]
    Empty,
    #[error("looks like a zip archive (.ifczip?): unzip it first")]
    Zip,
    #[error("looks like JSON (IFC5/ifcJSON?), which is not supported: expected an IFC STEP file")]
    Json,
    #[error("looks like XML (ifcXML?), which is not supported: expected an IFC STEP file")]
    Xml,
    #[error("not an IFC file: it does not start with the STEP header 'ISO-10303-21;'")]
    NoStepHeader,
    #[error("truncated or malformed: no end of HEADER section")]
    NoHeaderEnd,
    #[error("malformed header: no FILE_SCHEMA")]
    NoFileSchema,
    #[error("malformed FILE_SCHEMA")]
    MalformedFileSchema,
    #[error(
        "unknown IFC schema '{schema}' (bimtiles reads IFC2X3, IFC4, IFC4X1, IFC4X2 and IFC4X3)"
    )]
    UnknownSchema { schema: String },
    #[error("truncated: no DATA section")]
    NoDataSection,
    #[error("truncated: unclosed comment at line {line}")]
    UnclosedComment { line: usize },
    /// A record that breaks the `#id=TYPE(...);` form (`id`: when its number was read).
    #[error("malformed record{} at line {line}: {problem}", record_id(*id))]
    MalformedRecord {
        id: Option<u64>,
        line: usize,
        problem: RecordProblem,
    },
    #[error("truncated: record #{id} at line {line} is not terminated (the file ends inside it)")]
    UnterminatedRecord { id: u64, line: usize },
    #[error("truncated: the DATA section has no ENDSEC;")]
    NoDataEnd,
    #[error("truncated: no 'END-ISO-10303-21;' trailer")]
    NoTrailer,
    #[error("the DATA section holds no entities")]
    NoEntities,
    #[error("entity #{id} is defined twice (again at line {line}): entity ids must be unique")]
    DuplicateId { id: u64, line: usize },
    /// The first reference to an undefined record, and how many more there are.
    #[error("broken reference: #{from} refers to #{to}, which is not defined{}", more_text(*more))]
    BrokenReference { from: u32, to: u32, more: usize },
}

/// What is wrong with a malformed record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RecordProblem {
    #[error("expected '#id=' or ENDSEC;")]
    NotARecord,
    #[error("'#' without a number")]
    NoNumber,
    #[error("expected '='")]
    NoEquals,
    #[error("unbalanced ')'")]
    ExtraClosingParen,
    #[error("unbalanced parentheses")]
    UnbalancedParens,
    #[error("no attribute list")]
    NoAttributes,
    #[error("reference number out of range")]
    ReferenceOutOfRange,
}

fn record_id(id: Option<u64>) -> String {
    id.map_or(String::new(), |id| format!(" #{id}"))
}

fn more_text(more: usize) -> String {
    match more {
        0 => String::new(),
        _ => format!(" ({more} more broken references)"),
    }
}

type StepResult<T> = std::result::Result<T, StepError>;

/// Checks that `bytes` is a complete, well-formed IFC STEP file: header, known schema, DATA
/// records `#id=TYPE(...);` with balanced parentheses and closed strings, trailer, no reference
/// to an undefined `#id`. Returns the first problem found, naming its line.
pub fn check_step(bytes: &[u8]) -> StepResult<StepSummary> {
    let (schema, data_start) = check_header(bytes)?;
    let data = scan_data(bytes, data_start)?;
    if !data.ended {
        return Err(StepError::NoDataEnd);
    }
    if find(bytes, b"END-ISO-10303-21", data.end).is_none() {
        return Err(StepError::NoTrailer);
    }
    if data.entities == 0 {
        return Err(StepError::NoEntities);
    }
    if let Some(offset) = data.first_oversized_ref {
        return Err(StepError::MalformedRecord {
            id: None,
            line: line_of(bytes, offset),
            problem: RecordProblem::ReferenceOutOfRange,
        });
    }
    let mut broken = data.refs.iter().filter(|(r, _)| !data.defined.contains(*r));
    if let Some(&(to, from)) = broken.next() {
        return Err(StepError::BrokenReference {
            from,
            to,
            more: broken.count(),
        });
    }
    Ok(StepSummary {
        schema,
        entities: data.entities,
    })
}

/// Phase 1: the STEP header and a known FILE_SCHEMA. Returns the schema as written and where the
/// DATA section's records start.
fn check_header(bytes: &[u8]) -> StepResult<(String, usize)> {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace() && *b != 0xEF && *b != 0xBB && *b != 0xBF)
        .ok_or(StepError::Empty)?;
    let body = &bytes[start..];
    if !body.starts_with(b"ISO-10303-21;") {
        return Err(if body.starts_with(b"PK") {
            StepError::Zip
        } else if body.starts_with(b"{") {
            StepError::Json
        } else if body.starts_with(b"<") {
            StepError::Xml
        } else {
            StepError::NoStepHeader
        });
    }
    let hdr_end = find(bytes, b"ENDSEC;", start).ok_or(StepError::NoHeaderEnd)?;
    let header = &bytes[start..hdr_end];
    let fs = find(header, b"FILE_SCHEMA", 0).ok_or(StepError::NoFileSchema)?;
    let quote_after = |from: usize| {
        header[from..]
            .iter()
            .position(|&b| b == b'\'')
            .map(|p| p + from)
            .ok_or(StepError::MalformedFileSchema)
    };
    let q1 = quote_after(fs)?;
    let q2 = quote_after(q1 + 1)?;
    let schema = String::from_utf8_lossy(&header[q1 + 1..q2])
        .trim()
        .to_string();
    let up = schema.to_ascii_uppercase();
    if !KNOWN_SCHEMAS.iter().any(|k| up.starts_with(k)) {
        return Err(StepError::UnknownSchema { schema });
    }
    let data = find(bytes, b"DATA;", hdr_end).ok_or(StepError::NoDataSection)?;
    Ok((schema, data + 5))
}

/// The record ids defined so far: a bitset for the usual small ids, a set for the rest.
#[derive(Default)]
struct DefinedIds {
    small: Vec<u64>,
    big: HashSet<u64>,
}

/// Ids below this go in the bitset: at most 16 MiB of it, whatever a file's first id claims
/// (one `#2147483647=` record must not cost 256 MiB).
const SMALL_ID_LIMIT: u64 = 1 << 27;

impl DefinedIds {
    /// Adds `id`; false if it was defined already.
    fn insert(&mut self, id: u64) -> bool {
        if id < SMALL_ID_LIMIT {
            let w = (id / 64) as usize;
            if w >= self.small.len() {
                self.small.resize(w + 1, 0);
            }
            let was = self.small[w] & (1 << (id % 64)) != 0;
            self.small[w] |= 1 << (id % 64);
            !was
        } else {
            self.big.insert(id)
        }
    }

    fn contains(&self, id: u32) -> bool {
        let id = id as u64;
        let w = (id / 64) as usize;
        (w < self.small.len() && self.small[w] & (1 << (id % 64)) != 0) || self.big.contains(&id)
    }
}

/// What the pass over the DATA section found.
#[derive(Default)]
struct DataScan {
    defined: DefinedIds,
    /// (referenced id, id of the record that refers to it), checked once every record is known.
    refs: Vec<(u32, u32)>,
    /// Where the first record referring to an id past `u32::MAX` starts.
    first_oversized_ref: Option<usize>,
    entities: usize,
    /// Whether the section's ENDSEC; was found, and the offset after it (or the end of the file).
    ended: bool,
    end: usize,
}

/// Phase 2: every record of the DATA section, from `from` to its ENDSEC; (or the end of the file).
fn scan_data(bytes: &[u8], from: usize) -> StepResult<DataScan> {
    let n = bytes.len();
    let mut scan = DataScan::default();
    let mut i = from;
    while i < n {
        i = skip_ws_comments(bytes, i)?;
        if i >= n {
            break;
        }
        if bytes[i..].len() >= 7 && bytes[i..i + 7].eq_ignore_ascii_case(b"ENDSEC;") {
            scan.ended = true;
            i += 7;
            break;
        }
        let rec_start = i;
        let (id, body_start) = record_head(bytes, rec_start)?;
        i = record_body(bytes, id, rec_start, body_start, &mut scan)?;
        if !scan.defined.insert(id) {
            // Which of the two a reference means is undefined (ISO 10303-21 7.3.4: ids are unique).
            return Err(StepError::DuplicateId {
                id,
                line: line_of(bytes, rec_start),
            });
        }
        scan.entities += 1;
    }
    scan.end = i;
    Ok(scan)
}

/// Whitespace and `/* */` comments from `i`: the offset of the next token.
fn skip_ws_comments(bytes: &[u8], mut i: usize) -> StepResult<usize> {
    let n = bytes.len();
    loop {
        while i < n && bytes[i].is_ascii_whitespace() {
            i += 1;
        }
        if i + 1 < n && bytes[i] == b'/' && bytes[i + 1] == b'*' {
            match find(bytes, b"*/", i + 2) {
                Some(e) => i = e + 2,
                None => {
                    return Err(StepError::UnclosedComment {
                        line: line_of(bytes, i),
                    })
                }
            }
        } else {
            return Ok(i);
        }
    }
}

/// A record's `#id =` at `rec_start`: its id and the offset after the '='.
fn record_head(bytes: &[u8], rec_start: usize) -> StepResult<(u64, usize)> {
    let n = bytes.len();
    let malformed = |id, problem| StepError::MalformedRecord {
        id,
        line: line_of(bytes, rec_start),
        problem,
    };
    if bytes[rec_start] != b'#' {
        return Err(malformed(None, RecordProblem::NotARecord));
    }
    let ds = rec_start + 1;
    let (id, mut i) = read_number(bytes, ds);
    if i == ds {
        return Err(malformed(None, RecordProblem::NoNumber));
    }
    i = skip_ws_comments(bytes, i)?;
    if i >= n || bytes[i] != b'=' {
        return Err(malformed(Some(id), RecordProblem::NoEquals));
    }
    Ok((id, i + 1))
}

/// A record's body from `from` up to the ';' at depth 0 outside strings and comments, noting its
/// references in `scan`. Returns the offset after the ';'.
fn record_body(
    bytes: &[u8],
    id: u64,
    rec_start: usize,
    from: usize,
    scan: &mut DataScan,
) -> StepResult<usize> {
    let n = bytes.len();
    let malformed = |problem| StepError::MalformedRecord {
        id: Some(id),
        line: line_of(bytes, rec_start),
        problem,
    };
    let mut i = from;
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
                    return Err(malformed(RecordProblem::ExtraClosingParen));
                }
            }
            b'/' if i + 1 < n && bytes[i + 1] == b'*' => match find(bytes, b"*/", i + 2) {
                Some(e) => {
                    i = e + 2;
                    continue;
                }
                None => {
                    return Err(StepError::UnclosedComment {
                        line: line_of(bytes, i),
                    })
                }
            },
            b'#' => {
                let (r, j) = read_number(bytes, i + 1);
                if j > i + 1 {
                    if r <= u32::MAX as u64 {
                        scan.refs.push((r as u32, id.min(u32::MAX as u64) as u32));
                    } else if scan.first_oversized_ref.is_none() {
                        scan.first_oversized_ref = Some(rec_start);
                    }
                }
                i = j;
                continue;
            }
            b';' => {
                if depth != 0 {
                    return Err(malformed(RecordProblem::UnbalancedParens));
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
        return Err(StepError::UnterminatedRecord {
            id,
            line: line_of(bytes, rec_start),
        });
    }
    if !saw_paren || depth != 0 {
        return Err(malformed(RecordProblem::NoAttributes));
    }
    Ok(i)
}

/// The decimal number at `bytes[from..]` (saturating) and the index after its last digit
/// (`from` when there is no digit).
fn read_number(bytes: &[u8], from: usize) -> (u64, usize) {
    let mut value: u64 = 0;
    let mut i = from;
    while i < bytes.len() && bytes[i].is_ascii_digit() {
        value = value
            .saturating_mul(10)
            .saturating_add((bytes[i] - b'0') as u64);
        i += 1;
    }
    (value, i)
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "ISO-10303-21;\nHEADER;\nFILE_SCHEMA(('IFC4'));\nENDSEC;\nDATA;\n";

    fn check(data: &str) -> StepResult<StepSummary> {
        check_step(format!("{HEAD}{data}ENDSEC;\nEND-ISO-10303-21;\n").as_bytes())
    }

    #[test]
    fn problems_are_typed_with_their_line() {
        assert_eq!(check_step(b"PK\x03\x04").unwrap_err(), StepError::Zip);
        assert_eq!(check_step(b" \n").unwrap_err(), StepError::Empty);
        assert_eq!(check("").unwrap_err(), StepError::NoEntities);
        // HEAD is 5 lines: the first record is on line 6.
        let e = check("#1=IFCX((1.);\n").unwrap_err();
        assert_eq!(
            e,
            StepError::MalformedRecord {
                id: Some(1),
                line: 6,
                problem: RecordProblem::UnbalancedParens
            }
        );
        assert_eq!(
            e.to_string(),
            "malformed record #1 at line 6: unbalanced parentheses"
        );
        let e = check("#1=IFCX(1.);\nfoo\n").unwrap_err();
        assert_eq!(
            e.to_string(),
            "malformed record at line 7: expected '#id=' or ENDSEC;"
        );
        let e = check("#1=IFCX(#2,#3,#4);\n#2=IFCY(#1);\n").unwrap_err();
        assert_eq!(
            e,
            StepError::BrokenReference {
                from: 1,
                to: 3,
                more: 1
            }
        );
        assert!(e.to_string().ends_with("(1 more broken references)"), "{e}");
        let e = check("#1=IFCX(#99999999999);\n").unwrap_err();
        assert!(matches!(
            e,
            StepError::MalformedRecord {
                id: None,
                line: 6,
                problem: RecordProblem::ReferenceOutOfRange
            }
        ));
        assert!(matches!(
            check("#1=IFCX(1.) /* open\n").unwrap_err(),
            StepError::UnclosedComment { line: 6 }
        ));
        let s = check("#1=IFCX(#2);\n/* c */ #2 = IFCY('a;)');\n").unwrap();
        assert_eq!((s.schema.as_str(), s.entities), ("IFC4", 2));
    }
}

// ------------------------------------------------------------------------------------------------
// Scene assembly (ours, on plain data)
// ------------------------------------------------------------------------------------------------
