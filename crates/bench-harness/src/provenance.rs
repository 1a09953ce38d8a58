//! What ran: the commit and dirty flag the binary was built from, its build profile and
//! the machine's CPU, as every run's `metadata.json` (and a shard's manifest) records them.

/// The CPU's model name (`/proc/cpuinfo`; `unknown` where there is none).
pub(crate) fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown".into())
}

/// The commit of the workspace the binary was built from and whether its tracked files
/// differed from it then, recorded by `build.rs` (`None` when built outside a git checkout).
pub(crate) fn git_provenance() -> (Option<String>, Option<bool>) {
    (
        option_env!("EPD_GIT_COMMIT").map(str::to_string),
        option_env!("EPD_GIT_DIRTY").map(|d| d == "true"),
    )
}

/// The build profile of this binary: `dev` or `release`.
pub(crate) fn profile() -> &'static str {
    if cfg!(debug_assertions) {
        "dev"
    } else {
        "release"
    }
}
