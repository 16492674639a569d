//! Every output of `g1-train` through `output_file`'s one rule: never onto an input, a file the
//! deploy spec names (its weights, the estimator's model, the terrain network), or another output.
use std::path::Path;

pub use output_file::Kind;

/// Refuses `outputs` that would overwrite one another, one of `inputs`, or a file `spec` reads.
pub fn refuse_clashes(
    outputs: &[(&str, Option<&Path>, Kind)],
    inputs: &[(&str, Option<&Path>)],
    spec: Option<&control::spec::DeploySpec>,
) -> anyhow::Result<()> {
    let read = spec.map(|s| s.files_read()).unwrap_or_default();
    let mut ins = inputs.to_vec();
    ins.extend(read.iter().map(|(f, p)| (*f, Some(p.as_path()))));
    output_file::check_given(outputs, &ins)?;
    Ok(())
}
