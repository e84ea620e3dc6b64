//! JSON merge patches (RFC 7396), as `PATCH /v1/sessions/{id}` takes the
//! initialisation and tracker parameters: applying one, and its schema.
//!
//! A merge patch names only the fields to change; `null` removes a field,
//! which then takes its default when the result is read back. Its schema is
//! therefore the full schema with every field also allowed to be null
//! (nested objects recursively), derived here from the generated one so the
//! two never drift apart.

use std::collections::BTreeSet;

use serde_json::Value;
use utoipa::openapi::OpenApi as OpenApiDoc;

/// Applies `patch` to `target` (RFC 7396, section 2).
pub fn apply(target: &mut Value, patch: Value) {
    match patch {
        Value::Object(members) => {
            if !target.is_object() {
                *target = Value::Object(Default::default());
            }
            if let Value::Object(t) = target {
                for (key, value) in members {
                    if value.is_null() {
                        t.remove(&key);
                    } else {
                        apply(t.entry(key).or_insert(Value::Null), value);
                    }
                }
            }
        }
        other => *target = other,
    }
}

const SCHEMAS: &str = "#/components/schemas/";

/// The name of the merge-patch schema of the component `name`.
fn patch_name(name: &str) -> String {
    format!("{name}Patch")
}

/// Adds to `api` the merge-patch schema (`<Name>Patch`) of each component
/// in `roots` and of the object components they refer to, and points the
/// properties `fields` of the component `body` at them.
pub fn add_schemas(api: &mut OpenApiDoc, roots: &[&str], body: &str, fields: &[&str]) {
    let Some(components) = api.components.as_mut() else {
        return;
    };
    let mut full: serde_json::Map<String, Value> = components
        .schemas
        .iter()
        .filter_map(|(name, schema)| Some((name.clone(), serde_json::to_value(schema).ok()?)))
        .collect();
    let objects = object_components(&full);
    let mut todo: Vec<String> = roots.iter().map(|r| r.to_string()).collect();
    let mut done = BTreeSet::new();
    while let Some(name) = todo.pop() {
        if !done.insert(name.clone()) {
            continue;
        }
        let Some(schema) = full.get(&name) else {
            continue;
        };
        let patch = patch_schema(schema, &objects, &mut todo);
        full.insert(patch_name(&name), patch);
    }
    if let Some(Value::Object(b)) = full.get_mut(body) {
        if let Some(Value::Object(properties)) = b.get_mut("properties") {
            for field in fields {
                if let Some(p) = properties.get_mut(*field) {
                    retarget(p, &done, &mut Vec::new());
                }
            }
        }
    }
    let changed = done.iter().map(|n| patch_name(n)).chain([body.to_string()]);
    for name in changed {
        if let Some(schema) = full
            .get(&name)
            .and_then(|v| serde_json::from_value(v.clone()).ok())
        {
            components.schemas.insert(name, schema);
        }
    }
}

/// The names of the components that are objects (have properties): those
/// a merge patch merges into rather than replaces.
fn object_components(all: &serde_json::Map<String, Value>) -> BTreeSet<String> {
    all.iter()
        .filter(|(_, v)| v.get("properties").is_some())
        .map(|(k, _)| k.clone())
        .collect()
}

/// The merge-patch form of the object schema `schema`: no required
/// properties, no defaults, each property nullable, references to the
/// object components `objects` replaced by their patch schemas (queued on
/// `todo`).
fn patch_schema(schema: &Value, objects: &BTreeSet<String>, todo: &mut Vec<String>) -> Value {
    let mut patch = schema.clone();
    let Value::Object(p) = &mut patch else {
        return patch;
    };
    p.remove("required");
    p.remove("example");
    p.remove("default");
    if let Some(Value::Object(properties)) = p.get_mut("properties") {
        for property in properties.values_mut() {
            retarget(property, objects, todo);
            nullable(property);
        }
    }
    patch
}

/// Points every `$ref` in `value` to an object component of `objects` at
/// that component's patch schema, queueing it on `todo`.
fn retarget(value: &mut Value, objects: &BTreeSet<String>, todo: &mut Vec<String>) {
    match value {
        Value::Object(map) => {
            if let Some(Value::String(target)) = map.get_mut("$ref") {
                if let Some(name) = target.strip_prefix(SCHEMAS).map(str::to_string) {
                    if objects.contains(&name) {
                        *target = format!("{SCHEMAS}{}", patch_name(&name));
                        todo.push(name);
                    }
                }
            }
            map.values_mut().for_each(|v| retarget(v, objects, todo));
        }
        Value::Array(items) => items.iter_mut().for_each(|v| retarget(v, objects, todo)),
        _ => {}
    }
}

/// Makes the property schema `property` accept null, and drops its default
/// (a field left out of a patch keeps its value, not the default).
fn nullable(property: &mut Value) {
    let Value::Object(map) = property else {
        return;
    };
    map.remove("default");
    let null = Value::String("null".into());
    match map.get_mut("type") {
        Some(Value::Array(types)) => {
            if !types.contains(&null) {
                types.push(null);
            }
        }
        Some(single @ Value::String(_)) => *single = Value::Array(vec![single.clone(), null]),
        Some(_) => {}
        None => {
            let accepts_null = map
                .get("oneOf")
                .and_then(Value::as_array)
                .is_some_and(|alts| alts.iter().any(|a| a.get("type") == Some(&null)));
            if !accepts_null {
                let description = map.remove("description");
                let inner = Value::Object(std::mem::take(map));
                map.insert(
                    "oneOf".into(),
                    Value::Array(vec![inner, serde_json::json!({"type": "null"})]),
                );
                if let Some(d) = description {
                    map.insert("description".into(), d);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn null_removes_and_objects_merge() {
        let mut target = json!({"a": 1, "b": {"c": 2, "d": 3}});
        apply(&mut target, json!({"a": null, "b": {"c": 5}, "e": [1]}));
        assert_eq!(target, json!({"b": {"c": 5, "d": 3}, "e": [1]}));
    }

    #[test]
    fn a_patch_schema_accepts_null_everywhere_and_refers_to_patches() {
        let all: serde_json::Map<String, Value> = serde_json::from_value(json!({
            "Outer": {"type": "object", "required": ["n"], "properties": {
                "n": {"type": "number", "default": 1.0},
                "m": {"type": ["integer", "null"]},
                "inner": {"$ref": "#/components/schemas/Inner", "default": {}},
                "kind": {"$ref": "#/components/schemas/Kind"}
            }},
            "Inner": {"type": "object", "properties": {"b": {"type": "boolean"}}},
            "Kind": {"type": "string", "enum": ["a"]}
        }))
        .unwrap();
        let mut todo = Vec::new();
        let patch = patch_schema(&all["Outer"], &object_components(&all), &mut todo);
        assert_eq!(todo, ["Inner"]);
        assert_eq!(patch.get("required"), None);
        let p = &patch["properties"];
        assert_eq!(p["n"], json!({"type": ["number", "null"]}));
        assert_eq!(p["m"], json!({"type": ["integer", "null"]}));
        assert_eq!(
            p["inner"],
            json!({"oneOf": [{"$ref": "#/components/schemas/InnerPatch"}, {"type": "null"}]})
        );
        assert_eq!(
            p["kind"],
            json!({"oneOf": [{"$ref": "#/components/schemas/Kind"}, {"type": "null"}]})
        );
    }
}
