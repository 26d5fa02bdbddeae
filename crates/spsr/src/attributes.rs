//! Per-point and per-vertex attributes: named, typed columns of numbers.
//!
//! A point file often carries more than positions and normals: colours, intensities,
//! confidences, classifications, scanner time stamps. Every such numeric property is kept as
//! an [`Attribute`], a name and one value per point in the property's own type
//! ([`AttributeData`]). Keeping the type (rather than converting everything to `f64`) keeps
//! memory small (a `u8` colour channel is one byte per point, not eight) and lets writers
//! write a property back in the type it was read in.
//!
//! Colours are attributes named `red`, `green`, `blue` and optionally `alpha` (also
//! recognised: `r g b a` and `diffuse_red ...`), see [`find_colors`]. Integer colour channels
//! are in the full range of their type (`u8`: 0–255, `u16`: 0–65535); floating-point channels
//! are in `[0, 1]`.

/// The numeric type of an attribute column; the eight scalar types of PLY.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum ScalarType {
    /// Unsigned 8-bit integer.
    U8,
    /// Signed 8-bit integer.
    I8,
    /// Unsigned 16-bit integer.
    U16,
    /// Signed 16-bit integer.
    I16,
    /// Unsigned 32-bit integer.
    U32,
    /// Signed 32-bit integer.
    I32,
    /// 32-bit float.
    F32,
    /// 64-bit float.
    F64,
}

impl ScalarType {
    /// Size of one value in bytes.
    pub fn size(self) -> usize {
        match self {
            ScalarType::U8 | ScalarType::I8 => 1,
            ScalarType::U16 | ScalarType::I16 => 2,
            ScalarType::U32 | ScalarType::I32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }

    /// True for the integer types.
    pub fn is_integer(self) -> bool {
        !matches!(self, ScalarType::F32 | ScalarType::F64)
    }

    /// Smallest and largest value of an integer type; the finite range of a float type.
    pub fn range(self) -> (f64, f64) {
        match self {
            ScalarType::U8 => (0.0, u8::MAX as f64),
            ScalarType::I8 => (i8::MIN as f64, i8::MAX as f64),
            ScalarType::U16 => (0.0, u16::MAX as f64),
            ScalarType::I16 => (i16::MIN as f64, i16::MAX as f64),
            ScalarType::U32 => (0.0, u32::MAX as f64),
            ScalarType::I32 => (i32::MIN as f64, i32::MAX as f64),
            ScalarType::F32 => (f32::MIN as f64, f32::MAX as f64),
            ScalarType::F64 => (f64::MIN, f64::MAX),
        }
    }

    /// The PLY type name (`uchar`, `char`, `ushort`, `short`, `uint`, `int`, `float`,
    /// `double`).
    pub fn ply_name(self) -> &'static str {
        match self {
            ScalarType::U8 => "uchar",
            ScalarType::I8 => "char",
            ScalarType::U16 => "ushort",
            ScalarType::I16 => "short",
            ScalarType::U32 => "uint",
            ScalarType::I32 => "int",
            ScalarType::F32 => "float",
            ScalarType::F64 => "double",
        }
    }

    /// The smallest integer type that holds every integer in `min..=max`, or `F64` when no
    /// 32-bit type does.
    pub fn for_integer_range(min: i64, max: i64) -> ScalarType {
        let fits = |t: ScalarType| {
            let (lo, hi) = t.range();
            min as f64 >= lo && max as f64 <= hi
        };
        [
            ScalarType::U8,
            ScalarType::I8,
            ScalarType::U16,
            ScalarType::I16,
            ScalarType::U32,
            ScalarType::I32,
        ]
        .into_iter()
        .find(|&t| fits(t))
        .unwrap_or(ScalarType::F64)
    }
}

/// One value per point (or vertex), in one numeric type.
#[derive(Debug, Clone, PartialEq)]
pub enum AttributeData {
    /// Unsigned 8-bit integers.
    U8(Vec<u8>),
    /// Signed 8-bit integers.
    I8(Vec<i8>),
    /// Unsigned 16-bit integers.
    U16(Vec<u16>),
    /// Signed 16-bit integers.
    I16(Vec<i16>),
    /// Unsigned 32-bit integers.
    U32(Vec<u32>),
    /// Signed 32-bit integers.
    I32(Vec<i32>),
    /// 32-bit floats.
    F32(Vec<f32>),
    /// 64-bit floats.
    F64(Vec<f64>),
}

/// Runs `$body` with `$v` bound to the inner vector, whatever the variant.
macro_rules! each {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            AttributeData::U8($v) => $body,
            AttributeData::I8($v) => $body,
            AttributeData::U16($v) => $body,
            AttributeData::I16($v) => $body,
            AttributeData::U32($v) => $body,
            AttributeData::I32($v) => $body,
            AttributeData::F32($v) => $body,
            AttributeData::F64($v) => $body,
        }
    };
}

/// Converts `v` to an integer type: rounded to the nearest integer (halves away from zero),
/// clamped to the type's range; NaN becomes 0.
macro_rules! to_int {
    ($v:expr, $t:ty) => {{
        let v: f64 = $v;
        if v.is_nan() {
            0 as $t
        } else {
            v.round().clamp(<$t>::MIN as f64, <$t>::MAX as f64) as $t
        }
    }};
}

impl ScalarType {
    /// Appends `v` to `out` in this type, little endian, converted as by
    /// [`AttributeData::push_f64`] (the bytes a binary PLY holds for it).
    pub fn put_le(self, v: f64, out: &mut Vec<u8>) {
        match self {
            ScalarType::U8 => out.extend_from_slice(&to_int!(v, u8).to_le_bytes()),
            ScalarType::I8 => out.extend_from_slice(&to_int!(v, i8).to_le_bytes()),
            ScalarType::U16 => out.extend_from_slice(&to_int!(v, u16).to_le_bytes()),
            ScalarType::I16 => out.extend_from_slice(&to_int!(v, i16).to_le_bytes()),
            ScalarType::U32 => out.extend_from_slice(&to_int!(v, u32).to_le_bytes()),
            ScalarType::I32 => out.extend_from_slice(&to_int!(v, i32).to_le_bytes()),
            ScalarType::F32 => out.extend_from_slice(&(v as f32).to_le_bytes()),
            ScalarType::F64 => out.extend_from_slice(&v.to_le_bytes()),
        }
    }

    /// The value [`Self::put_le`] wrote at the start of `bytes`, as `f64` (exact for every
    /// type).
    ///
    /// # Panics
    /// If `bytes` is shorter than [`Self::size`].
    pub fn get_le(self, bytes: &[u8]) -> f64 {
        let b = |n: usize| -> &[u8] { &bytes[..n] };
        match self {
            ScalarType::U8 => f64::from(bytes[0]),
            ScalarType::I8 => f64::from(bytes[0] as i8),
            ScalarType::U16 => f64::from(u16::from_le_bytes(b(2).try_into().expect("2"))),
            ScalarType::I16 => f64::from(i16::from_le_bytes(b(2).try_into().expect("2"))),
            ScalarType::U32 => f64::from(u32::from_le_bytes(b(4).try_into().expect("4"))),
            ScalarType::I32 => f64::from(i32::from_le_bytes(b(4).try_into().expect("4"))),
            ScalarType::F32 => f64::from(f32::from_le_bytes(b(4).try_into().expect("4"))),
            ScalarType::F64 => f64::from_le_bytes(b(8).try_into().expect("8")),
        }
    }
}

impl AttributeData {
    /// An empty column of type `ty`.
    pub fn new(ty: ScalarType) -> Self {
        Self::with_capacity(ty, 0)
    }

    /// An empty column of type `ty` with room for `n` values.
    pub fn with_capacity(ty: ScalarType, n: usize) -> Self {
        match ty {
            ScalarType::U8 => AttributeData::U8(Vec::with_capacity(n)),
            ScalarType::I8 => AttributeData::I8(Vec::with_capacity(n)),
            ScalarType::U16 => AttributeData::U16(Vec::with_capacity(n)),
            ScalarType::I16 => AttributeData::I16(Vec::with_capacity(n)),
            ScalarType::U32 => AttributeData::U32(Vec::with_capacity(n)),
            ScalarType::I32 => AttributeData::I32(Vec::with_capacity(n)),
            ScalarType::F32 => AttributeData::F32(Vec::with_capacity(n)),
            ScalarType::F64 => AttributeData::F64(Vec::with_capacity(n)),
        }
    }

    /// A column of type `ty` holding `values`, each converted as by [`Self::push_f64`].
    pub fn from_f64(ty: ScalarType, values: impl IntoIterator<Item = f64>) -> Self {
        let values = values.into_iter();
        let mut data = Self::with_capacity(ty, values.size_hint().0);
        for v in values {
            data.push_f64(v);
        }
        data
    }

    /// A new column of this column's type holding `values` (e.g. values interpolated from this
    /// column onto mesh vertices), each converted as by [`Self::push_f64`].
    pub fn like_from_f64(&self, values: impl IntoIterator<Item = f64>) -> Self {
        Self::from_f64(self.scalar_type(), values)
    }

    /// The column's numeric type.
    pub fn scalar_type(&self) -> ScalarType {
        match self {
            AttributeData::U8(_) => ScalarType::U8,
            AttributeData::I8(_) => ScalarType::I8,
            AttributeData::U16(_) => ScalarType::U16,
            AttributeData::I16(_) => ScalarType::I16,
            AttributeData::U32(_) => ScalarType::U32,
            AttributeData::I32(_) => ScalarType::I32,
            AttributeData::F32(_) => ScalarType::F32,
            AttributeData::F64(_) => ScalarType::F64,
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        each!(self, v => v.len())
    }

    /// True when the column holds no value.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Value `i` as `f64` (exact for every type), or `None` past the end.
    #[allow(clippy::unnecessary_cast)] // the cast is a no-op only for the `F64` variant
    pub fn get(&self, i: usize) -> Option<f64> {
        each!(self, v => v.get(i).map(|&x| x as f64))
    }

    /// All values as `f64`, in order.
    #[allow(clippy::unnecessary_cast)] // the cast is a no-op only for the `F64` variant
    pub fn iter_f64(&self) -> impl Iterator<Item = f64> + '_ {
        (0..self.len()).map(move |i| each!(self, v => v[i] as f64))
    }

    /// Appends `v`, converted to the column's type: integer types round to the nearest
    /// integer (halves away from zero) and clamp to the type's range, NaN becomes 0; `F32`
    /// rounds to the nearest `f32`.
    pub fn push_f64(&mut self, v: f64) {
        match self {
            AttributeData::U8(d) => d.push(to_int!(v, u8)),
            AttributeData::I8(d) => d.push(to_int!(v, i8)),
            AttributeData::U16(d) => d.push(to_int!(v, u16)),
            AttributeData::I16(d) => d.push(to_int!(v, i16)),
            AttributeData::U32(d) => d.push(to_int!(v, u32)),
            AttributeData::I32(d) => d.push(to_int!(v, i32)),
            AttributeData::F32(d) => d.push(v as f32),
            AttributeData::F64(d) => d.push(v),
        }
    }

    /// Reserves room for `n` more values.
    pub fn reserve(&mut self, n: usize) {
        each!(self, v => v.reserve(n))
    }

    /// Appends the values of a column of the same type (another of a different type is
    /// converted as by [`AttributeData::push_f64`]).
    pub fn append(&mut self, other: AttributeData) {
        match (self, other) {
            (AttributeData::U8(a), AttributeData::U8(b)) => a.extend(b),
            (AttributeData::I8(a), AttributeData::I8(b)) => a.extend(b),
            (AttributeData::U16(a), AttributeData::U16(b)) => a.extend(b),
            (AttributeData::I16(a), AttributeData::I16(b)) => a.extend(b),
            (AttributeData::U32(a), AttributeData::U32(b)) => a.extend(b),
            (AttributeData::I32(a), AttributeData::I32(b)) => a.extend(b),
            (AttributeData::F32(a), AttributeData::F32(b)) => a.extend(b),
            (AttributeData::F64(a), AttributeData::F64(b)) => a.extend(b),
            (a, b) => {
                a.reserve(b.len());
                for v in b.iter_f64() {
                    a.push_f64(v);
                }
            }
        }
    }
}

/// A named per-point (or per-vertex) column of numbers.
#[derive(Debug, Clone, PartialEq)]
pub struct Attribute {
    /// The property name, as in the source file (`red`, `intensity`, `confidence`, ...).
    pub name: String,
    /// One value per point.
    pub data: AttributeData,
}

impl Attribute {
    /// An attribute called `name` holding `data`.
    pub fn new(name: impl Into<String>, data: AttributeData) -> Self {
        Self {
            name: name.into(),
            data,
        }
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        self.data.len()
    }

    /// True when the attribute holds no value.
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }
}

/// The attribute called `name` (ASCII case ignored), if any; the first one when several
/// match.
pub fn find<'a>(attributes: &'a [Attribute], name: &str) -> Option<&'a Attribute> {
    attributes
        .iter()
        .find(|a| a.name.eq_ignore_ascii_case(name))
}

/// The first attribute found, trying `names` in order (ASCII case ignored): e.g.
/// `find_any(attrs, CONFIDENCE_NAMES)`.
pub fn find_any<'a>(attributes: &'a [Attribute], names: &[&str]) -> Option<&'a Attribute> {
    names.iter().find_map(|n| find(attributes, n))
}

/// Names under which a per-point confidence is recognised, in order of preference.
pub const CONFIDENCE_NAMES: &[&str] = &["confidence", "quality"];

/// The colour name families recognised by [`find_colors`], in order of preference:
/// `[red, green, blue, alpha]`.
pub const COLOR_NAMES: &[[&str; 4]] = &[
    ["red", "green", "blue", "alpha"],
    ["r", "g", "b", "a"],
    [
        "diffuse_red",
        "diffuse_green",
        "diffuse_blue",
        "diffuse_alpha",
    ],
];

/// The colour channels of a point cloud or mesh, as found by [`find_colors`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Colors<'a> {
    /// Red channel.
    pub red: &'a Attribute,
    /// Green channel.
    pub green: &'a Attribute,
    /// Blue channel.
    pub blue: &'a Attribute,
    /// Alpha channel, when present.
    pub alpha: Option<&'a Attribute>,
}

/// A channel value mapped to `[0, 1]`: integers divided by their type's maximum (negative
/// values clamp to 0), floats clamped; NaN gives 0.
fn unit(data: &AttributeData, i: usize) -> f32 {
    let v = data.get(i).unwrap_or(0.0);
    let t = data.scalar_type();
    let u = if t.is_integer() { v / t.range().1 } else { v };
    if u.is_nan() {
        0.0
    } else {
        u.clamp(0.0, 1.0) as f32
    }
}

impl Colors<'_> {
    /// Number of colours (the length of the red channel).
    pub fn len(&self) -> usize {
        self.red.len()
    }

    /// True when there is no colour.
    pub fn is_empty(&self) -> bool {
        self.red.is_empty()
    }

    /// Colour `i` as `[r, g, b, a]` in `[0, 1]` (alpha 1 when there is no alpha channel).
    /// Integer channels are divided by their type's maximum (255 for `u8`, 65535 for `u16`);
    /// float channels are taken to be in `[0, 1]` already and clamped. Values past the end
    /// of a channel read as 0.
    pub fn unit(&self, i: usize) -> [f32; 4] {
        [
            unit(&self.red.data, i),
            unit(&self.green.data, i),
            unit(&self.blue.data, i),
            self.alpha.map_or(1.0, |a| unit(&a.data, i)),
        ]
    }
}

/// The colour channels among `attributes`: the first family of [`COLOR_NAMES`] whose red,
/// green and blue are all present (ASCII case ignored), with its alpha when present.
pub fn find_colors(attributes: &[Attribute]) -> Option<Colors<'_>> {
    COLOR_NAMES.iter().find_map(|[r, g, b, a]| {
        Some(Colors {
            red: find(attributes, r)?,
            green: find(attributes, g)?,
            blue: find(attributes, b)?,
            alpha: find(attributes, a),
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_read_back_are_the_value_in_its_type() {
        use ScalarType::*;
        for ty in [U8, I8, U16, I16, U32, I32, F32, F64] {
            for v in [-70000.7, -3.5, 0.0, 0.1, 2.5, 255.0, 1e10] {
                let mut bytes = Vec::new();
                ty.put_le(v, &mut bytes);
                assert_eq!(bytes.len(), ty.size());
                let typed = AttributeData::from_f64(ty, [v]).get(0).unwrap();
                assert_eq!(ty.get_le(&bytes).to_bits(), typed.to_bits(), "{ty:?} {v}");
            }
        }
    }

    #[test]
    fn push_rounds_and_clamps_to_the_type() {
        let mut d = AttributeData::new(ScalarType::U8);
        for v in [-3.0, 0.4, 0.5, 254.5, 300.0, f64::NAN, f64::INFINITY] {
            d.push_f64(v);
        }
        assert_eq!(d, AttributeData::U8(vec![0, 0, 1, 255, 255, 0, 255]));
        let d = AttributeData::from_f64(ScalarType::I16, [-40000.0, -1.5, 1.5, 7.0]);
        assert_eq!(d, AttributeData::I16(vec![i16::MIN, -2, 2, 7]));
        let d = AttributeData::from_f64(ScalarType::F32, [0.1]);
        assert_eq!(d, AttributeData::F32(vec![0.1f32]));
        let like = d.like_from_f64([2.0, 3.0]);
        assert_eq!(like.scalar_type(), ScalarType::F32);
        assert_eq!(like.iter_f64().collect::<Vec<_>>(), vec![2.0, 3.0]);
    }

    #[test]
    fn get_is_exact_for_every_type() {
        let cases = [
            AttributeData::U32(vec![u32::MAX]),
            AttributeData::I32(vec![i32::MIN]),
            AttributeData::F64(vec![0.1]),
            AttributeData::I8(vec![-128]),
        ];
        let expected = [u32::MAX as f64, i32::MIN as f64, 0.1, -128.0];
        for (d, e) in cases.iter().zip(expected) {
            assert_eq!(d.get(0), Some(e));
            assert_eq!(d.get(1), None);
            assert_eq!(d.len(), 1);
        }
    }

    #[test]
    fn integer_range_picks_the_smallest_type() {
        assert_eq!(ScalarType::for_integer_range(0, 255), ScalarType::U8);
        assert_eq!(ScalarType::for_integer_range(-1, 100), ScalarType::I8);
        assert_eq!(ScalarType::for_integer_range(0, 65535), ScalarType::U16);
        assert_eq!(ScalarType::for_integer_range(-1, 200), ScalarType::I16);
        assert_eq!(ScalarType::for_integer_range(0, 1 << 20), ScalarType::U32);
        assert_eq!(ScalarType::for_integer_range(-1, 1 << 20), ScalarType::I32);
        assert_eq!(ScalarType::for_integer_range(0, 1 << 40), ScalarType::F64);
    }

    #[test]
    fn colours_are_found_by_any_family_and_scaled_by_type() {
        let attrs = vec![
            Attribute::new("quality", AttributeData::F32(vec![0.5])),
            Attribute::new("R", AttributeData::U16(vec![65535])),
            Attribute::new("g", AttributeData::U16(vec![0])),
            Attribute::new("b", AttributeData::U16(vec![32768])),
        ];
        let c = find_colors(&attrs).unwrap();
        assert!(c.alpha.is_none());
        let u = c.unit(0);
        assert_eq!(u[0], 1.0);
        assert_eq!(u[1], 0.0);
        assert!((u[2] - 0.5).abs() < 1e-4);
        assert_eq!(u[3], 1.0);
        assert_eq!(find_any(&attrs, CONFIDENCE_NAMES).unwrap().name, "quality");
        let attrs = vec![
            Attribute::new("diffuse_red", AttributeData::F32(vec![2.0])),
            Attribute::new("diffuse_green", AttributeData::F32(vec![-1.0])),
            Attribute::new("diffuse_blue", AttributeData::F32(vec![f32::NAN])),
            Attribute::new("diffuse_alpha", AttributeData::U8(vec![51])),
        ];
        let u = find_colors(&attrs).unwrap().unit(0);
        assert_eq!(u, [1.0, 0.0, 0.0, 0.2]);
        assert!(find_colors(&attrs[..2]).is_none());
    }
}
