//! CityGML attributes as typed element properties (set `attributes`): generic attributes
//! (CityGML 2.0 `gen:stringAttribute name="…"`/`gen:value`, 3.0 `gen:StringAttribute` with
//! `gen:name`/`gen:value`, and the int/double/date/uri/measure kinds), the core and thematic
//! fields of CityGML 2.0 §6–§10 (measuredHeight, function, usage, yearOfConstruction,
//! storeysAboveGround…), and Application Domain Extension fields, kept as text under their
//! namespace prefix (`uro:buildingID`).

use crate::scene::PropertyValue;

/// Whether an element opens a generic attribute (not a set: a set's members are read one by one).
pub(super) fn is_generic_attribute(ns: &[u8], local: &str) -> bool {
    let generics = ns.starts_with(b"http://www.opengis.net/citygml/")
        && ns.windows(8).any(|w| w == b"generics");
    let kind = local.to_ascii_lowercase();
    generics
        && matches!(
            kind.as_str(),
            "stringattribute"
                | "intattribute"
                | "doubleattribute"
                | "dateattribute"
                | "uriattribute"
                | "measureattribute"
        )
}

/// A generic attribute being read.
#[derive(Debug)]
pub(super) struct GenericAttribute {
    kind: String,
    name: Option<String>,
    value: Option<String>,
}

impl GenericAttribute {
    pub(super) fn new(local: &str, name: Option<String>) -> Self {
        GenericAttribute {
            kind: local.to_ascii_lowercase(),
            name,
            value: None,
        }
    }

    /// A child field (`name`, `value`).
    pub(super) fn field(&mut self, local: &str, text: &str) {
        match local {
            "name" => self.name = Some(text.to_string()),
            "value" => self.value = Some(text.to_string()),
            _ => {}
        }
    }

    /// The property, typed by the attribute's kind (a number that does not parse stays text).
    pub(super) fn finish(self) -> Option<(String, PropertyValue)> {
        let (name, value) = (self.name?, self.value?);
        let typed = match self.kind.as_str() {
            "intattribute" => integer(&value),
            "doubleattribute" | "measureattribute" => number(&value),
            _ => None,
        };
        Some((name, typed.unwrap_or(PropertyValue::Text(value))))
    }
}

fn integer(text: &str) -> Option<PropertyValue> {
    text.trim().parse().ok().map(PropertyValue::Integer)
}

fn number(text: &str) -> Option<PropertyValue> {
    text.trim()
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .map(PropertyValue::Number)
}

/// A core or thematic field of a city object, typed; `None` for fields not kept.
pub(super) fn core_attribute(local: &str, text: &str) -> Option<(String, PropertyValue)> {
    let value = match local {
        "measuredHeight" => number(text),
        // A year, or in CityGML 3.0 a date: the year is kept as a number when it is one.
        "yearOfConstruction" | "yearOfDemolition" => {
            integer(text).or_else(|| Some(PropertyValue::Text(text.to_string())))
        }
        "storeysAboveGround" | "storeysBelowGround" => integer(text),
        "function" | "usage" | "class" | "roofType" | "name" | "description" => {
            Some(PropertyValue::Text(text.to_string()))
        }
        _ => None,
    };
    value.map(|v| (local.to_string(), v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generic_attributes_are_typed_by_kind() {
        let mut a = GenericAttribute::new("intAttribute", Some("floors".into()));
        a.field("value", "4");
        assert_eq!(
            a.finish(),
            Some(("floors".into(), PropertyValue::Integer(4)))
        );
        let mut a = GenericAttribute::new("DoubleAttribute", None);
        a.field("name", "h");
        a.field("value", "not a number");
        assert_eq!(
            a.finish(),
            Some(("h".into(), PropertyValue::Text("not a number".into())))
        );
        assert_eq!(
            core_attribute("measuredHeight", "12.5"),
            Some(("measuredHeight".into(), PropertyValue::Number(12.5)))
        );
        assert_eq!(core_attribute("creationDate", "2020-01-01"), None);
    }
}
