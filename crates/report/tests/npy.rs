//! What `NpyWriter` writes reads back bit for bit, with an index that names it.

use diffphys_report::npy::{NpyEntry, NpyWriter};
use diffphys_tape::test_array;
use ndarray::ArrayD;
use ndarray_npy::read_npy;

#[test]
fn arrays_read_back_bit_for_bit_and_the_index_names_them() {
    let dir = std::env::temp_dir().join(format!("diffphys-npy-{}", std::process::id()));
    let mut npy = NpyWriter::new(&dir).unwrap();
    let field = test_array::<f64>(&[5, 7], 1).mapv(|v| v * 1e-300); // subnormal-range values too
    let grad = test_array::<f32>(&[3, 2, 4], 2);
    npy.write("field", field.view(), "a field").unwrap();
    npy.write("grad_f32", grad.view(), "a gradient").unwrap();
    assert!(npy.write("field", field.view(), "again").is_err());
    assert!(npy.write("../escape", field.view(), "a path").is_err());
    let index = npy.finish().unwrap();

    let back: ArrayD<f64> = read_npy(dir.join("field.npy")).unwrap();
    assert_eq!(back.shape(), field.shape());
    assert!(back
        .iter()
        .zip(&field)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    let back32: ArrayD<f32> = read_npy(dir.join("grad_f32.npy")).unwrap();
    assert!(back32
        .iter()
        .zip(&grad)
        .all(|(a, b)| a.to_bits() == b.to_bits()));

    let entries: Vec<NpyEntry> =
        serde_json::from_str(&std::fs::read_to_string(index).unwrap()).unwrap();
    assert_eq!(entries.len(), 2);
    assert_eq!(entries[0].shape, vec![5, 7]);
    assert_eq!(entries[0].dtype, "float64");
    assert_eq!(entries[1].dtype, "float32");
    assert_eq!(entries[1].file, "grad_f32.npy");
}
