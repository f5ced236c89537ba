//! Prints the parameter cells of the quick profiles (lead's lab).
fn main() -> anyhow::Result<()> {
    for (model, profile) in [(psf_db::PsfModel::LensMotion, precompute::Profile::Quick), (psf_db::PsfModel::ThinLens, precompute::Profile::Quick)] {
        let spec = profile.spec(model);
        let n = psf_db::ParamSpace::resolution_for_count(spec.ranges.len(), spec.psf_count).unwrap();
        let space = psf_db::ParamSpace::for_model(model, &spec.ranges, n)?;
        println!("{model:?}: n {n}, {} cells", space.psf_count());
        for i in 0..space.psf_count() {
            let b = space.cell_box(i).unwrap();
            println!("  {i}: {:?}", b);
        }
    }
    Ok(())
}
