use pyo3::prelude::*;

#[pymodule]
fn _subdfit(_m: &Bound<'_, PyModule>) -> PyResult<()> {
    Ok(())
}
