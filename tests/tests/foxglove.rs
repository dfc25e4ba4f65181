//! The run log's 3D scene (`/scene`, `/tf`) read by the upstream Python `mcap` reader
//! and decoded with the classes of Foxglove's own `foxglove-schemas-protobuf` package
//! (both from PyPI into `.deps/pytest`): the schemas are Foxglove's, every message
//! decodes, each logged episode starts with its bodies as entities and moves them with
//! one transform set per step, stamped the env's step duration apart; `ess replay
//! --mcap` writes a re-simulated episode's robot with the same poses.

use ess_tests::{SMOKE, ess, pytest_path, python};
use serde_json::Value;

const READ_WITH_MCAP_AND_FOXGLOVE: &str = r#"
import json, sys
from mcap.reader import make_reader
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from google.protobuf import descriptor_pb2
upstream = {"/scene": SceneUpdate, "/tf": FrameTransforms}
out = {"schemas": {}, "scenes": [], "tf": [], "steps": 0}
with open(sys.argv[1], "rb") as f:
    for schema, ch, msg in make_reader(f).iter_messages(topics=["/scene", "/tf", "/eval/step"]):
        if ch.topic == "/eval/step":
            out["steps"] += 1
            continue
        cls = upstream[ch.topic]
        fds = descriptor_pb2.FileDescriptorSet()
        fds.ParseFromString(schema.data)
        name = cls.DESCRIPTOR.full_name
        ours = [m for fd in fds.file for m in fd.message_type if fd.package + "." + m.name == name]
        out["schemas"][ch.topic] = {
            "name": schema.name, "upstream": name, "encoding": schema.encoding,
            "fields": sorted(f.name for f in ours[0].field) if ours else [],
            "upstream_fields": sorted(f.name for f in cls.DESCRIPTOR.fields),
        }
        m = cls()
        m.ParseFromString(msg.data)
        if ch.topic == "/scene":
            out["scenes"].append({"t": msg.log_time, "entities": [
                {"id": e.id, "frame": e.frame_id, "n": len(e.cubes) + len(e.spheres) + len(e.cylinders),
                 "meta": {kv.key: kv.value for kv in e.metadata}} for e in m.entities]})
        else:
            out["tf"].append({"t": msg.log_time, "tf": [
                [t.parent_frame_id, t.child_frame_id, t.translation.x, t.translation.y, t.translation.z,
                 t.rotation.x ** 2 + t.rotation.y ** 2 + t.rotation.z ** 2 + t.rotation.w ** 2]
                for t in m.transforms]})
json.dump(out, sys.stdout)
"#;

/// `ess replay RUN/run.mcap --episode 0 --mcap OUT`.
fn replay_first_episode(run: &std::path::Path, out: &std::path::Path) -> std::process::Output {
    ess(&[
        "replay",
        &run.join("run.mcap").display().to_string(),
        "--episode",
        "0",
        "--mcap",
        &out.display().to_string(),
    ])
}

#[test]
fn a_reacher_run_log_plays_its_episodes_as_foxglove_scenes() {
    let d = tempfile::tempdir().unwrap();
    let run = d.path().join("run");
    let run_s = run.display().to_string();
    let mut args = vec![
        "train", "--env", "reacher", "--actors", "0", "--out", &run_s,
    ];
    args.extend_from_slice(SMOKE);
    let r = ess(&args);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let out = python(
        READ_WITH_MCAP_AND_FOXGLOVE,
        &[run.join("run.mcap").as_os_str()],
    );
    assert!(
        out.status.success(),
        "mcap / foxglove-schemas-protobuf (PYTHONPATH {}; `bash scripts/bootstrap.sh --nextest` installs them) failed: {}",
        pytest_path().display(),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    for topic in ["/scene", "/tf"] {
        let s = &v["schemas"][topic];
        assert_eq!(s["name"], s["upstream"], "{topic}: {s}");
        assert_eq!(s["encoding"], "protobuf");
        assert_eq!(
            s["fields"], s["upstream_fields"],
            "{topic}: the embedded schema is Foxglove's"
        );
    }
    let scenes = v["scenes"].as_array().unwrap();
    let tfs = v["tf"].as_array().unwrap();
    let steps = v["steps"].as_u64().unwrap() as usize;
    // The final evaluation: one scene per episode, a transform set at its start and
    // after each step.
    assert!(!scenes.is_empty());
    assert_eq!(tfs.len(), steps + scenes.len());
    let first = &scenes[0]["entities"];
    let frames: Vec<&str> = first
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["frame"].as_str().unwrap())
        .collect();
    for body in ["world", "upper_arm", "forearm"] {
        assert!(frames.contains(&body), "{frames:?}");
    }
    assert!(
        first
            .as_array()
            .unwrap()
            .iter()
            .all(|e| e["n"].as_u64().unwrap() >= 1)
    );
    assert_eq!(first[0]["meta"]["episode"], "0");
    // Each transform names a body with an entity, in unit quaternions; steps 20 ms
    // apart (Reacher: 2 x 0.01 s).
    let ep: Vec<&Value> = tfs
        .iter()
        .take_while(|t| t["t"].as_u64() < scenes.get(1).and_then(|s| s["t"].as_u64()))
        .collect();
    assert!(
        ep.len() > 10,
        "{} transform sets in the first episode",
        ep.len()
    );
    let t0 = ep[0]["t"].as_u64().unwrap();
    assert_eq!(t0, scenes[0]["t"].as_u64().unwrap());
    for (k, t) in ep.iter().enumerate() {
        assert_eq!(t["t"].as_u64().unwrap(), t0 + 20_000_000 * k as u64);
        for row in t["tf"].as_array().unwrap() {
            assert_eq!(row[0], "world");
            assert!(frames.contains(&row[1].as_str().unwrap()), "{row}");
            assert!((row[5].as_f64().unwrap() - 1.0).abs() < 1e-9, "{row}");
        }
    }
    // The forearm moves.
    let x = |t: &Value| t["tf"][1][2].as_f64().unwrap();
    assert!(
        ep.iter().any(|t| (x(t) - x(ep[0])).abs() > 1e-3),
        "the arm never moved"
    );
    // `ess replay --mcap`: the re-simulated episode 0 alone, the same poses as logged.
    let ep_mcap = d.path().join("ep0.mcap");
    let r = replay_first_episode(&run, &ep_mcap);
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let out = python(READ_WITH_MCAP_AND_FOXGLOVE, &[ep_mcap.as_os_str()]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let w: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(w["scenes"].as_array().unwrap().len(), 1);
    assert_eq!(w["scenes"][0]["entities"], scenes[0]["entities"]);
    let replayed = w["tf"].as_array().unwrap();
    assert_eq!(replayed.len(), ep.len());
    for (a, b) in replayed.iter().zip(&ep) {
        assert_eq!(a["tf"], b["tf"], "replayed poses equal the logged ones");
    }
    let t0 = replayed[0]["t"].as_u64().unwrap();
    for (k, t) in replayed.iter().enumerate() {
        assert_eq!(t["t"].as_u64().unwrap(), t0 + 20_000_000 * k as u64);
    }
    // An env without bodies has nothing to draw: one line, exit 2.
    let t2d = d.path().join("t2d");
    let t2d_s = t2d.display().to_string();
    let mut args = vec!["train", "--actors", "0", "--out", &t2d_s];
    args.extend_from_slice(SMOKE);
    assert!(ess(&args).status.success());
    let r = replay_first_episode(&t2d, &d.path().join("x.mcap"));
    assert_eq!(r.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&r.stderr).contains("no bodies to draw"));
}
