//! The batch job files in `deploy/` run for real: `deploy/slurm/test-cluster.sh` starts a one-node
//! Slurm cluster and submits the Slurm job files unchanged (sharded precompute, a cancelled and
//! resubmitted part, the refused and the completed merge, a frame range in three tasks), and
//! `deploy/kubernetes/validate.sh` checks the Indexed Job manifests against the Kubernetes API
//! schema (offline; no Kubernetes cluster runs them here). docs/BATCH.md points at those files
//! instead of holding copies that could drift.
//!
//! With `SPREADLET_REQUIRE_SLURM=1` (set by `.ci/run`, which installs slurm-wlm and munge) a
//! missing Slurm is a failure; without it, a machine with no Slurm skips the cluster test and says
//! so. `SPREADLET_REQUIRE_KUBERNETES_VALIDATE=1` does the same for the schema check, which runs
//! the `kubernetes-validate` on PATH or the one `KUBERNETES_VALIDATE` names.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use spreadlet_e2e::{binary, cache_dir};

/// The workspace root (where `deploy/` and `docs/` are).
fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn required(var: &str) -> bool {
    std::env::var(var).is_ok_and(|v| v == "1")
}

/// Whether `tool` is an executable on PATH or in /usr/sbin (where Debian puts the daemons).
fn installed(tool: &str) -> bool {
    let on_path = std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join(tool).is_file()));
    on_path || Path::new("/usr/sbin").join(tool).is_file()
}

/// Runs `script` with bash, kills it after `limit` (its own waits are bounded too; this is the
/// last guard against a hang) and panics with its output when it fails.
fn run_script(script: &Path, envs: &[(&str, &Path)], limit: Duration) -> String {
    let log = tempfile::NamedTempFile::new().expect("log file");
    let mut cmd = Command::new("bash");
    cmd.arg(script)
        .current_dir(repo())
        .stdin(Stdio::null())
        .stdout(log.reopen().expect("log file"))
        .stderr(log.reopen().expect("log file"));
    for (k, v) in envs {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("bash starts");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().expect("wait on the script") {
            break status;
        }
        if start.elapsed() > limit {
            // SIGKILL would skip the script's cleanup trap; SIGTERM runs it.
            let _ = Command::new("kill")
                .args(["-TERM", &child.id().to_string()])
                .status();
            std::thread::sleep(Duration::from_secs(20));
            let _ = child.kill();
            let _ = child.wait();
            let output = std::fs::read_to_string(log.path()).unwrap_or_default();
            panic!(
                "{} did not finish within {limit:?}:\n{output}",
                script.display()
            );
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    let output = std::fs::read_to_string(log.path()).unwrap_or_default();
    assert!(
        status.success(),
        "{} failed ({status}):\n{output}",
        script.display()
    );
    output
}

#[test]
fn the_slurm_job_files_run_on_a_real_cluster() {
    let tools = ["munged", "slurmctld", "slurmd", "sbatch", "scontrol"];
    let missing: Vec<&str> = tools.into_iter().filter(|t| !installed(t)).collect();
    if !missing.is_empty() {
        assert!(
            !required("SPREADLET_REQUIRE_SLURM"),
            "SPREADLET_REQUIRE_SLURM=1 but {} not installed (Debian: apt-get install slurm-wlm \
             munge)",
            missing.join(", ")
        );
        eprintln!(
            "skipped: no Slurm here ({} missing); set SPREADLET_REQUIRE_SLURM=1 to make this a \
             failure",
            missing.join(", ")
        );
        return;
    }
    // The job files get the binaries of this build, not whatever is on PATH.
    let bin_dir = binary("precompute")
        .parent()
        .expect("binaries live in a folder")
        .to_path_buf();
    for name in ["spreadlet", "spreadlet-scene"] {
        binary(name);
    }
    let cache = cache_dir();
    let output = run_script(
        &repo().join("deploy/slurm/test-cluster.sh"),
        &[("SPREADLET_BIN", &bin_dir), ("SPREADLET_CACHE", &cache)],
        Duration::from_secs(15 * 60),
    );
    assert!(
        output.contains("passed:"),
        "the cluster test did not report its end:\n{output}"
    );
    eprintln!("{output}");
}

#[test]
fn the_kubernetes_manifests_match_the_api_schema() {
    let validator = std::env::var_os("KUBERNETES_VALIDATE")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("kubernetes-validate"));
    let found = Command::new(&validator)
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !found {
        assert!(
            !required("SPREADLET_REQUIRE_KUBERNETES_VALIDATE"),
            "SPREADLET_REQUIRE_KUBERNETES_VALIDATE=1 but {} does not run (pip install \
             kubernetes-validate, or set KUBERNETES_VALIDATE to it)",
            validator.display()
        );
        eprintln!(
            "skipped: kubernetes-validate is not installed (pip install kubernetes-validate; \
             KUBERNETES_VALIDATE names it when it is not on PATH)"
        );
        return;
    }
    let output = run_script(
        &repo().join("deploy/kubernetes/validate.sh"),
        &[("KUBERNETES_VALIDATE", &validator)],
        Duration::from_secs(120),
    );
    assert!(
        output.contains("valid against the Kubernetes API schema"),
        "the validation did not report:\n{output}"
    );
    eprintln!("{output}");
}

/// The number in `key: N` (the first such line) of a manifest.
fn yaml_number(manifest: &str, key: &str) -> Option<u32> {
    manifest.lines().find_map(|line| {
        line.trim()
            .strip_prefix(key)
            .and_then(|rest| rest.strip_prefix(':'))
            .and_then(|v| v.trim().parse().ok())
    })
}

/// An Indexed Job runs `completions` pods with indices 0..completions-1; `--shard auto/N` must
/// split into exactly that many parts, or parts go missing (N larger) or the last pods fail (N
/// smaller). The schema cannot see this; the text can.
#[test]
fn the_indexed_jobs_split_into_as_many_parts_as_they_have_pods() {
    for name in ["precompute-shard-job.yaml", "synth-frames-job.yaml"] {
        let path = repo().join("deploy/kubernetes").join(name);
        let manifest = std::fs::read_to_string(&path).expect("manifest");
        assert!(
            manifest.contains("completionMode: Indexed"),
            "{name} is not an Indexed Job"
        );
        let completions = yaml_number(&manifest, "completions").expect("completions");
        let parallelism = yaml_number(&manifest, "parallelism").expect("parallelism");
        assert!(
            parallelism <= completions,
            "{name}: parallelism {parallelism} > completions {completions}"
        );
        let shards: Vec<&str> = manifest
            .lines()
            .filter_map(|l| l.trim().trim_start_matches("- ").strip_prefix("auto/"))
            .collect();
        assert_eq!(
            shards,
            vec![completions.to_string().as_str()],
            "{name}: --shard auto/N must name N = completions = {completions}"
        );
    }
}

/// Every job file and manifest in `deploy/` is named in docs/BATCH.md, and the doc holds no job
/// script or manifest of its own: the files are the one copy, and they are what is tested.
#[test]
fn the_batch_doc_points_at_the_deploy_files() {
    let doc = std::fs::read_to_string(repo().join("docs/BATCH.md")).expect("docs/BATCH.md");
    for dir in ["deploy/slurm", "deploy/kubernetes"] {
        let mut names: Vec<String> = std::fs::read_dir(repo().join(dir))
            .expect("deploy folder")
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert!(!names.is_empty(), "{dir} is empty");
        for name in names {
            let path = format!("{dir}/{name}");
            assert!(doc.contains(&path), "docs/BATCH.md does not mention {path}");
        }
    }
    for copy in ["#SBATCH", "apiVersion:", "completionMode:"] {
        assert!(
            !doc.contains(copy),
            "docs/BATCH.md holds its own job text ({copy}): point at the file in deploy/ instead"
        );
    }
}
