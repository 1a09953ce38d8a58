//! Points and per-point values taken from Python objects: numpy arrays read in place
//! when they are C-contiguous aligned float64, converted once otherwise, masked points
//! dropped; and points handed back as an (N, 3) array without a copy.

use super::*;

/// Points or per-point values taken from a Python object: a read-only borrow of a
/// float64 array, either the caller's own (no copy) or a converted copy.
pub(crate) struct Taken<A> {
    /// The borrowed array.
    pub(crate) array: A,
    /// Whether the values were copied (converted dtype, layout or a non-array object).
    pub(crate) copied: bool,
}

/// `obj` as a numpy array (`numpy.asarray`, which makes a new array of anything but an
/// array), checked: real numbers (integer or float) in `ndim` dimensions, the second of
/// length 3 for points; `name` starts the error messages.
pub(crate) fn as_real_array<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    ndim: usize,
) -> PyResult<Bound<'py, PyAny>> {
    let py = obj.py();
    let np = py.import("numpy")?;
    // An Open3D PointCloud (or any object holding its points in `points`) that is no
    // array itself: its points.
    let held;
    let obj = if name == "points"
        && !obj.is_instance_of::<numpy::PyUntypedArray>()
        && !obj.hasattr("__array__")?
        && !obj.hasattr("__array_interface__")?
        && obj.hasattr("points")?
    {
        held = obj.getattr("points")?;
        &held
    } else {
        obj
    };
    let obj = &unmasked(obj, name)?;
    let arr = np
        .call_method1("asarray", (obj,))
        .map_err(|e| PyValueError::new_err(format!("{name}: not an array of numbers: {e}")))?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyValueError::new_err(format!(
            "{name}: dtype {} is not a real number type (float or integer){}",
            dtype.str()?,
            if kind == "O" {
                "; an Open3D point cloud or a list of objects? pass numpy.asarray(pcd.points), \
                 an (N, 3) array of numbers"
            } else {
                ""
            }
        )));
    }
    let shape: Vec<usize> = arr.getattr("shape")?.extract()?;
    let ok = shape.len() == ndim && (ndim != 2 || shape[1] == 3);
    if !ok {
        let want = if ndim == 2 { "(N, 3)" } else { "(N,)" };
        return Err(PyValueError::new_err(format!(
            "{name}: expected an array of shape {want}, got shape {shape:?}"
        )));
    }
    Ok(arr)
}

/// A masked array (`numpy.ma.MaskedArray`) as the values it stands for: its data when
/// nothing is masked (no copy); for points, a float64 copy with every masked value NaN, so
/// that each point with a masked coordinate is dropped and counted in `n_dropped` as an
/// invalid pixel is; for per-point values (`intensity`, `sigma`) a `ValueError`, since
/// dropping a value would misalign it with its point. Anything else as it is.
pub(crate) fn unmasked<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Bound<'py, PyAny>> {
    let py = obj.py();
    let ma = py.import("numpy.ma")?;
    if !obj.is_instance(&ma.getattr("MaskedArray")?)? {
        return Ok(obj.clone());
    }
    let any_masked: bool = ma
        .call_method1("getmaskarray", (obj,))?
        .call_method0("any")?
        .extract()?;
    if !any_masked {
        return obj.getattr("data");
    }
    if name != "points" {
        return Err(PyValueError::new_err(format!(
            "{name}: a masked array with masked values; pass the points and values without \
             the masked entries (e.g. points[~mask], {name}[~mask]) or fill them"
        )));
    }
    let np = py.import("numpy")?;
    let floats = obj.call_method1("astype", (np.getattr("float64")?,))?;
    floats.call_method1("filled", (f64::NAN,))
}

/// The array itself when it is float64 (native byte order), aligned and C-contiguous;
/// else a converted C-contiguous float64 copy.
pub(crate) fn contiguous_f64<'py>(arr: Bound<'py, PyAny>) -> PyResult<(Bound<'py, PyAny>, bool)> {
    let fits = match arr.cast::<numpy::PyUntypedArray>() {
        Ok(a) => {
            a.is_c_contiguous()
                && arr
                    .getattr("flags")?
                    .getattr("aligned")?
                    .extract::<bool>()?
                && a.dtype().is_equiv_to(&numpy::dtype::<f64>(arr.py()))
        }
        Err(_) => false,
    };
    if fits {
        return Ok((arr, false));
    }
    let np = arr.py().import("numpy")?;
    let f64_type = np.getattr("float64")?;
    let copy = np.call_method1("ascontiguousarray", (arr, f64_type))?;
    Ok((copy, true))
}

/// Points from an (N, 3) array of real numbers (or anything `numpy.asarray` makes one
/// of): the caller's float64 C-contiguous array is borrowed, anything else copied once.
pub(crate) fn take_points<'py>(
    obj: &Bound<'py, PyAny>,
) -> PyResult<Taken<PyReadonlyArray2<'py, f64>>> {
    let arr = as_real_array(obj, "points", 2)?;
    let made = !obj.is_instance_of::<numpy::PyUntypedArray>();
    let (arr, converted) = contiguous_f64(arr)?;
    let copied = made || converted;
    let arr = arr.cast_into::<PyArray2<f64>>()?;
    let array = arr
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("points: {e}")))?;
    Ok(Taken { array, copied })
}

/// Per-point values (intensity, σ) from a 1-D array of real numbers.
pub(crate) fn take_values<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Taken<PyReadonlyArray1<'py, f64>>> {
    let arr = as_real_array(obj, name, 1)?;
    let made = !obj.is_instance_of::<numpy::PyUntypedArray>();
    let (arr, converted) = contiguous_f64(arr)?;
    let copied = made || converted;
    let arr = arr.cast_into::<PyArray1<f64>>()?;
    let array = arr
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{name}: {e}")))?;
    Ok(Taken { array, copied })
}

/// The points of a borrowed (N, 3) array as `[x, y, z]` rows, in place.
pub(crate) fn rows<'a>(a: &'a PyReadonlyArray2<'_, f64>) -> PyResult<&'a [[f64; 3]]> {
    let flat = a
        .as_slice()
        .map_err(|_| PyValueError::new_err("points: the array is not contiguous"))?;
    let (rows, rest) = flat.as_chunks::<3>();
    if !rest.is_empty() {
        return Err(PyValueError::new_err("points: expected 3 values per point"));
    }
    Ok(rows)
}

/// The values of a borrowed 1-D array, in place.
pub(crate) fn values<'a>(a: &'a PyReadonlyArray1<'_, f64>, name: &str) -> PyResult<&'a [f64]> {
    a.as_slice()
        .map_err(|_| PyValueError::new_err(format!("{name}: the array is not contiguous")))
}

/// An `(N, 3)` float64 array owning `points` (no copy).
pub(crate) fn points_array<'py>(
    py: Python<'py>,
    points: Vec<[f64; 3]>,
) -> PyResult<Bound<'py, PyAny>> {
    let n = points.len();
    let flat = PyArray1::from_vec(py, points.into_flattened());
    Ok(flat.reshape([n, 3])?.into_any())
}
