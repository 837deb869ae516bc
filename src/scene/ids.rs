//! Element ids that stay unique whatever the source repeats (book: guide/bim-models.md, "Element
//! ids").
//!
//! glTF lets sibling nodes share a name, and many exporters write `object` several times under
//! one parent; a model may also repeat a GlobalId, and two input files may hold the same ids.
//! Picking, aliases, dedup bookkeeping and `inspect --feature` all need one element per id, so:
//!
//! 1. **Same-named siblings.** Among the children of one node (or the scene's root nodes), in
//!    their glTF order, the first node of a name keeps it and the n-th repeat (n ≥ 1) is told apart
//!    by `#n` in its path segment: `object`, `object#1`, `object#2`. ([`number_same_named`])
//! 2. **GlobalIds win when unique.** A GlobalId (from the extras, or an IFC-GUID-shaped node name)
//!    is the id unless another element of the file has it too; then each of them uses its path.
//! 3. **Anything still repeated** (a node literally named `object#1` beside two `object`s, several
//!    input files with the same ids) keeps its first holder, in reading order, and each later
//!    holder gets the smallest `#k` (k ≥ 1) that makes it unique. ([`make_keys_unique`])
//!
//! Every step depends on the input alone, so ids are the same across runs and in every process of
//! a sharded build.

use super::ElementTable;
use std::collections::{HashMap, HashSet};

/// For each sibling group (node indices in their source order), the repeat number of each node
/// among the same-named ones before it: 0 for the first of a name (and for unnamed nodes, whose
/// `node{i}` segment is unique already), n for the n-th repeat. `names[i]` is node i's name.
pub fn number_same_named<'a>(
    names: &[Option<&'a str>],
    groups: impl IntoIterator<Item = &'a [u32]>,
) -> Vec<u32> {
    let mut repeat = vec![0u32; names.len()];
    let mut seen: HashMap<&str, u32> = HashMap::new();
    for group in groups {
        seen.clear();
        for &node in group {
            let Some(name) = names.get(node as usize).copied().flatten() else {
                continue;
            };
            let count = seen.entry(name).or_insert(0);
            repeat[node as usize] = *count;
            *count += 1;
        }
    }
    repeat
}

/// One path segment: the name, `node{i}` when unnamed, `#n` added for the n-th repeat.
pub fn path_segment(name: Option<&str>, index: u32, repeat: u32) -> String {
    match (name, repeat) {
        (Some(n), 0) => n.to_string(),
        (Some(n), r) => format!("{n}#{r}"),
        (None, _) => format!("node{index}"),
    }
}

/// Step 3 of the module doc on keys in reading order: each key already held by an earlier one
/// gets the smallest free `#k`. Returns how many changed.
pub fn make_unique(keys: &mut [String]) -> usize {
    let mut taken: HashSet<String> = HashSet::with_capacity(keys.len());
    let mut repeated = false;
    for key in keys.iter() {
        repeated |= !taken.insert(key.clone());
    }
    if !repeated {
        return 0;
    }
    // `taken` holds every key once: a later holder must avoid all of them, and the new keys too.
    let mut held: HashSet<String> = HashSet::with_capacity(taken.len());
    let mut renamed = 0;
    for key in keys.iter_mut() {
        if held.insert(key.clone()) {
            continue;
        }
        let free = (1u32..)
            .map(|k| format!("{key}#{k}"))
            .find(|c| !taken.contains(c))
            .expect("a free suffix");
        taken.insert(free.clone());
        held.insert(free.clone());
        *key = free;
        renamed += 1;
    }
    renamed
}

/// [`make_unique`] on the keys of a table (re-encoded only when a key changes); returns the table
/// and how many keys changed.
pub fn make_keys_unique(elements: ElementTable) -> (ElementTable, usize) {
    let mut keys: Vec<String> = elements.iter().map(|e| e.key).collect();
    let renamed = make_unique(&mut keys);
    if renamed == 0 {
        return (elements, 0);
    }
    let mut keys = keys.into_iter();
    let table = elements.map(|info| info.key = keys.next().expect("one key per element"));
    (table, renamed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ElementInfo;

    #[test]
    fn repeats_are_numbered_per_sibling_group() {
        let names = [
            Some("object"),
            Some("object"),
            None,
            Some("door"),
            Some("object"),
            Some("object"),
        ];
        // Two parents: [0, 1, 2, 3] and [4, 5]; repeats count within a group only.
        let groups: [&[u32]; 2] = [&[0, 1, 2, 3], &[4, 5]];
        assert_eq!(number_same_named(&names, groups), vec![0, 1, 0, 0, 0, 1]);
        assert_eq!(path_segment(Some("object"), 1, 1), "object#1");
        assert_eq!(path_segment(Some("door"), 3, 0), "door");
        assert_eq!(path_segment(None, 2, 0), "node2");
    }

    fn table(keys: &[&str]) -> ElementTable {
        let mut t = ElementTable::default();
        for k in keys {
            t.push(&ElementInfo::keyed(*k));
        }
        t
    }

    #[test]
    fn later_holders_get_the_smallest_free_suffix() {
        let (t, renamed) = make_keys_unique(table(&["a", "a#1", "a", "b", "a", "b"]));
        let keys: Vec<String> = t.iter().map(|e| e.key).collect();
        assert_eq!(keys, ["a", "a#1", "a#2", "b", "a#3", "b#1"]);
        assert_eq!(renamed, 3);
        let (t, renamed) = make_keys_unique(table(&["x", "y"]));
        assert_eq!(renamed, 0);
        assert_eq!(t.len(), 2);
    }
}
