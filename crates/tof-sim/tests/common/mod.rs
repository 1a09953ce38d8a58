pub mod determinism;
pub mod oracle;
