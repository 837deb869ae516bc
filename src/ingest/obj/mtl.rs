//! Wavefront MTL material libraries (Wavefront "Alias|Wavefront MTL" format, as `mtllib` names
//! them): per `newmtl`, the diffuse colour `Kd`, opacity `d` (or its complement `Tr`) and the
//! diffuse map `map_Kd` with its options (`-s`/`-o` scale and offset of the UVs, `-clamp`). Other
//! statements (specular, illumination models, bump maps) do not change what a tile draws and are
//! skipped.

use std::collections::HashMap;

/// One `newmtl` as written.
#[derive(Debug, Clone, PartialEq)]
pub struct MtlMaterial {
    pub diffuse: [f32; 3],
    /// `d` (or `1 - Tr`); 1 is opaque.
    pub opacity: f32,
    pub diffuse_map: Option<TextureMap>,
}

impl Default for MtlMaterial {
    fn default() -> Self {
        MtlMaterial {
            diffuse: [0.8, 0.8, 0.8],
            opacity: 1.0,
            diffuse_map: None,
        }
    }
}

/// A `map_Kd` statement: the file as written and the options that change how it is drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct TextureMap {
    pub file: String,
    /// `-s u v`: UVs are multiplied by this (default 1 1).
    pub scale: [f32; 2],
    /// `-o u v`: then offset by this (default 0 0).
    pub offset: [f32; 2],
    /// `-clamp on`: no repeat outside 0..1.
    pub clamp: bool,
}

/// How many arguments an option takes (`-o`, `-s`, `-t` take one to three numbers).
fn option_arity(option: &str) -> Option<(usize, usize)> {
    Some(match option {
        "-blendu" | "-blendv" | "-cc" | "-clamp" | "-imfchan" | "-texres" | "-bm" | "-boost"
        | "-type" => (1, 1),
        "-mm" => (2, 2),
        "-o" | "-s" | "-t" => (1, 3),
        _ => return None,
    })
}

/// Parses a `map_Kd` statement's arguments; `None` when it names no file.
pub fn parse_map(args: &str) -> Option<TextureMap> {
    let tokens: Vec<&str> = args.split_whitespace().collect();
    let mut map = TextureMap {
        file: String::new(),
        scale: [1.0, 1.0],
        offset: [0.0, 0.0],
        clamp: false,
    };
    let mut k = 0;
    while k < tokens.len() {
        let Some((min, max)) = option_arity(tokens[k]) else {
            break;
        };
        let option = tokens[k];
        k += 1;
        let mut values = Vec::new();
        while values.len() < max && k < tokens.len() {
            // Numeric options stop at the first non-number (the file name).
            let numeric = matches!(option, "-o" | "-s" | "-t" | "-mm" | "-bm" | "-boost");
            match (numeric, tokens[k].parse::<f32>()) {
                (true, Ok(v)) => values.push(v.to_string()),
                (true, Err(_)) if values.len() >= min => break,
                _ => values.push(tokens[k].to_string()),
            }
            k += 1;
        }
        let number = |i: usize, default: f32| {
            values
                .get(i)
                .and_then(|v| v.parse::<f32>().ok())
                .filter(|v| v.is_finite())
                .unwrap_or(default)
        };
        match option {
            "-s" => map.scale = [number(0, 1.0), number(1, 1.0)],
            "-o" => map.offset = [number(0, 0.0), number(1, 0.0)],
            "-clamp" => map.clamp = values.first().is_some_and(|v| v == "on"),
            _ => {}
        }
    }
    // The file name is the rest: names may hold spaces.
    map.file = tokens[k.min(tokens.len())..].join(" ");
    (!map.file.is_empty()).then_some(map)
}

/// Parses an MTL file's text into its materials by name (the last definition of a repeated name
/// wins, as in the tools that write them).
pub fn parse_mtl(text: &str) -> HashMap<String, MtlMaterial> {
    let mut out = HashMap::new();
    let mut current: Option<(String, MtlMaterial)> = None;
    let numbers = |rest: &str| -> Vec<f32> {
        rest.split_whitespace()
            .map_while(|t| t.parse::<f32>().ok())
            .filter(|v| v.is_finite())
            .collect()
    };
    // Whether `d` was given: it wins over `Tr` whatever their order.
    let mut has_d = false;
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (keyword, rest) = line.split_once(char::is_whitespace).unwrap_or((line, ""));
        let rest = rest.trim();
        if keyword == "newmtl" {
            if let Some((name, m)) = current.take() {
                out.insert(name, m);
            }
            current = Some((rest.to_string(), MtlMaterial::default()));
            has_d = false;
            continue;
        }
        let Some((_, m)) = current.as_mut() else {
            continue;
        };
        match keyword {
            "Kd" => {
                let v = numbers(rest);
                if let [r, g, b, ..] = v[..] {
                    m.diffuse = [r, g, b].map(|c| c.clamp(0.0, 1.0));
                } else if let [g] = v[..] {
                    m.diffuse = [g.clamp(0.0, 1.0); 3];
                }
            }
            "d" => {
                if let Some(&d) = numbers(rest).first() {
                    m.opacity = d.clamp(0.0, 1.0);
                    has_d = true;
                }
            }
            "Tr" if !has_d => {
                if let Some(&t) = numbers(rest).first() {
                    m.opacity = (1.0 - t).clamp(0.0, 1.0);
                }
            }
            "map_Kd" => m.diffuse_map = parse_map(rest),
            _ => {}
        }
    }
    if let Some((name, m)) = current {
        out.insert(name, m);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_options_and_names_with_spaces() {
        let m = parse_map("-s 2 3 1 -o 0.5 0.25 -clamp on -bm 0.3 my facade.jpg").unwrap();
        assert_eq!(m.file, "my facade.jpg");
        assert_eq!(m.scale, [2.0, 3.0]);
        assert_eq!(m.offset, [0.5, 0.25]);
        assert!(m.clamp);
        let m = parse_map("-s 2 tex.png").unwrap();
        assert_eq!((m.file.as_str(), m.scale), ("tex.png", [2.0, 1.0]));
        assert_eq!(parse_map("-clamp on"), None);
        assert_eq!(parse_map(r"D:\a\b.jpg").unwrap().file, r"D:\a\b.jpg");
    }

    #[test]
    fn materials_take_kd_d_and_tr() {
        let lib = parse_mtl(
            "newmtl a\n\tKd 0.1 0.2 0.3\n\tTr 0.25\n\tmap_Kd a.jpg\nnewmtl b\nd 0.5\nTr 0.0\n# x\nnewmtl c\n",
        );
        assert_eq!(lib.len(), 3);
        assert_eq!(lib["a"].diffuse, [0.1, 0.2, 0.3]);
        assert_eq!(lib["a"].opacity, 0.75);
        assert_eq!(lib["a"].diffuse_map.as_ref().unwrap().file, "a.jpg");
        assert_eq!(lib["b"].opacity, 0.5, "d wins over Tr");
        assert_eq!(lib["c"], MtlMaterial::default());
    }
}
