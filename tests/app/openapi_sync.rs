//! The committed OpenAPI documents (`openapi/openapi.yaml`, `.json`) are
//! exactly what the code generates. Regenerate after changing a route or a
//! schema with:
//!
//! ```text
//! cargo run -- openapi --format yaml > openapi/openapi.yaml
//! cargo run -- openapi --format json > openapi/openapi.json
//! ```

use std::path::Path;

fn committed(name: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi").join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn committed_yaml_matches_the_code() {
    assert!(
        committed("openapi.yaml") == semdepth::service::openapi_yaml_text(),
        "openapi/openapi.yaml is out of date: run `cargo run -- openapi --format yaml > openapi/openapi.yaml`"
    );
}

#[test]
fn committed_json_matches_the_code() {
    assert!(
        committed("openapi.json") == semdepth::service::openapi_json_text(),
        "openapi/openapi.json is out of date: run `cargo run -- openapi --format json > openapi/openapi.json`"
    );
}

#[test]
fn every_operation_has_an_id_and_every_v1_error_is_described() {
    let api: serde_json::Value = serde_json::from_str(semdepth::service::openapi_json_text()).unwrap();
    let paths = api["paths"].as_object().unwrap();
    // The contract's paths are all there.
    for path in [
        "/v1/calibrations",
        "/v1/calibrations/{id}",
        "/v1/calibrations/{id}/samples",
        "/v1/sessions",
        "/v1/sessions/{id}",
        "/v1/sessions/{id}/frames",
        "/v1/sessions/{id}/reset",
        "/v1/sessions/{id}/reinit",
        "/v1/sessions/{id}/results",
        "/v1/sessions/{id}/calibration-samples",
        "/v1/sessions/{id}/stream",
        "/v1/depth",
        "/healthz",
        "/readyz",
        "/metrics",
        "/openapi.json",
    ] {
        assert!(paths.contains_key(path), "missing path {path}");
    }
    for (path, item) in paths {
        for (method, op) in item.as_object().unwrap() {
            assert!(
                op["operationId"].is_string(),
                "{method} {path} has no operationId"
            );
            if path.starts_with("/v1") {
                assert!(
                    op["responses"]["401"].is_object(),
                    "{method} {path} does not describe 401"
                );
            }
        }
    }
}

/// Every link (issue #66) names an operation that exists and fills exactly
/// its path parameters, and the operations that take a session's, an
/// object's or a calibration's id are reached from their creators.
#[test]
fn links_lead_from_creators_to_the_operations_that_take_their_ids() {
    let api: serde_json::Value = serde_json::from_str(semdepth::service::openapi_json_text()).unwrap();
    let mut path_params = std::collections::BTreeMap::new();
    for item in api["paths"].as_object().unwrap().values() {
        for op in item.as_object().unwrap().values() {
            let Some(id) = op["operationId"].as_str() else {
                continue;
            };
            let params: std::collections::BTreeSet<String> = op["parameters"]
                .as_array()
                .into_iter()
                .flatten()
                .filter(|p| p["in"] == "path")
                .map(|p| p["name"].as_str().unwrap().to_string())
                .collect();
            path_params.insert(id.to_string(), params);
        }
    }
    let mut reached = std::collections::BTreeSet::new();
    for item in api["paths"].as_object().unwrap().values() {
        for op in item.as_object().unwrap().values() {
            for response in op["responses"].as_object().into_iter().flatten().map(|(_, r)| r) {
                for (name, link) in response["links"].as_object().into_iter().flatten() {
                    let target = link["operationId"].as_str().unwrap();
                    let expected = path_params
                        .get(target)
                        .unwrap_or_else(|| panic!("link {name} to unknown operation {target}"));
                    let given: std::collections::BTreeSet<String> =
                        link["parameters"].as_object().unwrap().keys().cloned().collect();
                    assert_eq!(&given, expected, "link {name} to {target}");
                    reached.insert(target.to_string());
                }
            }
        }
    }
    for target in [
        "upload_pair",
        "latest_frame_image",
        "add_session_calibration_sample",
        "add_object",
        "delete_object",
        "add_calibration_sample",
    ] {
        assert!(reached.contains(target), "no link reaches {target}");
    }
}
