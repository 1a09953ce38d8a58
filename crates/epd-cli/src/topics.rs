//! `epd topics`: the topics of ROS 2 bags with their message types and counts
//! (`epd_frame::bag::topics`), one table per bag on standard output.

use std::io::Write;
use std::process::ExitCode;

use anyhow::Context;
use epd_frame::bag::topics;
use epd_io::stderr_line;

use crate::args::TopicsArgs;

/// Print each bag's topics; exit 1 when a bag could not be read or was damaged (its
/// topics counted up to the damage are printed first).
pub fn run_topics(a: &TopicsArgs) -> anyhow::Result<ExitCode> {
    let mut out = std::io::stdout().lock();
    let mut failed = false;
    for bag in &a.bags {
        let shown = epd_io::name::shown(bag);
        let t = match topics(bag) {
            Ok(t) => t,
            Err(e) => {
                stderr_line!("error: {}", epd_io::name::escape_controls(&e.to_string()));
                failed = true;
                continue;
            }
        };
        let width = t
            .topics
            .iter()
            .map(|i| i.topic.chars().count())
            .max()
            .unwrap_or(5);
        let tw = t
            .topics
            .iter()
            .map(|i| i.message_type.chars().count())
            .max()
            .unwrap_or(4);
        let mut text = format!(
            "{shown}:\n  {:<width$}  {:<tw$}  {:>8}\n",
            "topic", "type", "messages"
        );
        for i in &t.topics {
            text.push_str(&format!(
                "  {:<width$}  {:<tw$}  {:>8}\n",
                epd_io::name::escape_controls(&i.topic),
                epd_io::name::escape_controls(&i.message_type),
                i.count
            ));
        }
        out.write_all(text.as_bytes())
            .and_then(|()| out.flush())
            .context("cannot write to standard output")?;
        if let Some(e) = &t.damaged {
            stderr_line!(
                "error: {} (the counts above stop there)",
                epd_io::name::escape_controls(&e.to_string())
            );
            failed = true;
        }
    }
    Ok(if failed {
        ExitCode::FAILURE
    } else {
        ExitCode::SUCCESS
    })
}
