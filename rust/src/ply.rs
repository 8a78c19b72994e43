//! A PLY reader for the common layout of face scans: binary (both byte orders) or ASCII, one
//! `vertex` element (scalar properties, `x y z` among them, optional `red green blue [alpha]` as
//! uchar) followed by one `face` element holding only a `vertex_indices` / `vertex_index` list of
//! triangles or quads (the same count on every row).
//!
//! It is a fast path, not a second implementation of every PLY: anything else (texture
//! coordinates or a `TextureFile`, other elements, float colours, mixed polygon sizes, a body of
//! the wrong length, a number it would have to guess about, ...) returns `Err(reason)` and the
//! caller reads the file as before (trimesh), so broken or unusual files get exactly today's
//! answer. On the files it takes it gives what trimesh gives: float properties rounded to f32,
//! quads split into `[0 1 2]` (all of them first) then `[2 3 0]`, indices unchecked (the caller
//! validates them).

/// A PLY read by the fast path.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyMesh {
    pub vertices: Vec<[f64; 3]>,
    /// Triangles, raw file indices (not range-checked here).
    pub faces: Vec<[i64; 3]>,
    /// Vertex colours, `channels` (3 or 4) bytes per vertex, when the file has them.
    pub colors: Option<(Vec<u8>, usize)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn parse(s: &str) -> Option<Ty> {
        Some(match s {
            "char" | "int8" => Ty::I8,
            "uchar" | "uint8" => Ty::U8,
            "short" | "int16" => Ty::I16,
            "ushort" | "uint16" => Ty::U16,
            "int" | "int32" => Ty::I32,
            "uint" | "uint32" => Ty::U32,
            "float" | "float32" => Ty::F32,
            "double" | "float64" => Ty::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64)
    }

    /// The value at `b` (exactly `size()` bytes) as f64 (integers exact, float rounded as stored).
    fn read(self, b: &[u8], big: bool) -> f64 {
        macro_rules! rd {
            ($t:ty, $n:expr) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(b);
                (if big { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) }) as f64
            }};
        }
        match self {
            Ty::I8 => b[0] as i8 as f64,
            Ty::U8 => b[0] as f64,
            Ty::I16 => rd!(i16, 2),
            Ty::U16 => rd!(u16, 2),
            Ty::I32 => rd!(i32, 4),
            Ty::U32 => rd!(u32, 4),
            Ty::F32 => rd!(f32, 4),
            Ty::F64 => rd!(f64, 8),
        }
    }

    /// An integer's range (for ASCII tokens).
    fn range(self) -> (i64, i64) {
        match self {
            Ty::I8 => (i8::MIN as i64, i8::MAX as i64),
            Ty::U8 => (0, u8::MAX as i64),
            Ty::I16 => (i16::MIN as i64, i16::MAX as i64),
            Ty::U16 => (0, u16::MAX as i64),
            Ty::I32 => (i32::MIN as i64, i32::MAX as i64),
            Ty::U32 => (0, u32::MAX as i64),
            Ty::F32 | Ty::F64 => (i64::MIN, i64::MAX),
        }
    }
}

struct Header {
    ascii: bool,
    big: bool,
    /// Vertex properties in file order.
    vprops: Vec<(String, Ty)>,
    n_vertices: usize,
    /// Face list (count type, index type).
    flist: (Ty, Ty),
    n_faces: usize,
    /// Byte offset of the body.
    body: usize,
}

fn fallback<T>(why: &str) -> Result<T, String> {
    Err(why.to_string())
}

fn parse_header(data: &[u8]) -> Result<Header, String> {
    let mut pos = 0usize;
    let mut lines: Vec<String> = Vec::new();
    loop {
        let Some(nl) = data[pos..].iter().position(|&c| c == b'\n') else {
            return fallback("no end of header");
        };
        let raw = &data[pos..pos + nl];
        pos += nl + 1;
        if !raw.iter().all(|&c| c.is_ascii() && (c >= b' ' || c == b'\t' || c == b'\r')) {
            return fallback("non-ASCII or control bytes in the header");
        }
        let line = std::str::from_utf8(raw).map_err(|_| "header not text".to_string())?;
        let line = line.strip_suffix('\r').unwrap_or(line);
        if line.contains('\r') {
            return fallback("a CR inside a header line");
        }
        let toks: Vec<&str> = line.split_ascii_whitespace().collect();
        if toks.contains(&"end_header") {
            if toks.len() != 1 {
                return fallback("end_header with other words");
            }
            break;
        }
        lines.push(line.to_string());
        if lines.len() > 1000 {
            return fallback("a very long header");
        }
    }
    if lines.len() < 2 || lines[0].trim() != "ply" {
        return fallback("no 'ply' line");
    }
    let f: Vec<&str> = lines[1].split_ascii_whitespace().collect();
    if f.len() != 3 || f[0] != "format" || f[2] != "1.0" {
        return fallback("unusual format line");
    }
    let (ascii, big) = match f[1] {
        "ascii" => (true, false),
        "binary_little_endian" => (false, false),
        "binary_big_endian" => (false, true),
        _ => return fallback("unknown format"),
    };
    // elements: (name, count, scalar props, list props)
    #[allow(clippy::type_complexity)]
    let mut elements: Vec<(String, usize, Vec<(String, Ty)>, Vec<(String, Ty, Ty)>)> = Vec::new();
    for line in &lines[2..] {
        let t: Vec<&str> = line.split_ascii_whitespace().collect();
        if t.is_empty() {
            return fallback("an empty header line");
        }
        if line.to_ascii_lowercase().contains("texturefile") {
            return fallback("a texture file");
        }
        match t[0] {
            "comment" | "obj_info" => {}
            "element" => {
                if t.len() != 3 || t[2].is_empty() || !t[2].bytes().all(|c| c.is_ascii_digit()) || t[2].len() > 12 {
                    return fallback("unusual element line");
                }
                elements.push((t[1].to_string(), t[2].parse::<usize>().map_err(|e| e.to_string())?, vec![], vec![]));
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return fallback("a property before any element");
                };
                if t.len() == 3 {
                    let Some(ty) = Ty::parse(t[1]) else { return fallback("unknown property type") };
                    el.2.push((t[2].to_string(), ty));
                } else if t.len() == 5 && t[1] == "list" {
                    let (Some(a), Some(b)) = (Ty::parse(t[2]), Ty::parse(t[3])) else {
                        return fallback("unknown list type");
                    };
                    el.3.push((t[4].to_string(), a, b));
                } else {
                    return fallback("unusual property line");
                }
            }
            _ => return fallback("an unknown header line"),
        }
    }
    if elements.len() != 2 || elements[0].0 != "vertex" || elements[1].0 != "face" {
        return fallback("not exactly a vertex and a face element");
    }
    let (_, n_vertices, vprops, vlists) = elements[0].clone();
    let (_, n_faces, fprops, flists) = elements[1].clone();
    if n_vertices == 0 || n_faces == 0 {
        return fallback("an empty element");
    }
    if !vlists.is_empty() || !fprops.is_empty() || flists.len() != 1 {
        return fallback("unusual properties");
    }
    let (fname, fc, fi) = &flists[0];
    if fname != "vertex_indices" && fname != "vertex_index" {
        return fallback("face list not named vertex_indices");
    }
    if !fc.is_int() || !fi.is_int() {
        return fallback("non-integer face list");
    }
    let names: Vec<&str> = vprops.iter().map(|(n, _)| n.as_str()).collect();
    for (k, n) in names.iter().enumerate() {
        if names[..k].contains(n) {
            return fallback("a repeated vertex property");
        }
    }
    for n in ["x", "y", "z"] {
        if !names.contains(&n) {
            return fallback("no x y z");
        }
    }
    for n in ["texture_u", "texture_v", "u", "v", "s", "t", "texcoord"] {
        if names.contains(&n) {
            return fallback("texture coordinates");
        }
    }
    let colour: Vec<&(String, Ty)> =
        vprops.iter().filter(|(n, _)| matches!(n.as_str(), "red" | "green" | "blue" | "alpha")).collect();
    if !colour.is_empty() {
        let has = |c: &str| names.contains(&c);
        if !(has("red") && has("green") && has("blue")) || colour.iter().any(|(_, t)| *t != Ty::U8) {
            return fallback("colours other than uchar red green blue [alpha]");
        }
    }
    Ok(Header { ascii, big, vprops, n_vertices, flist: (*fc, *fi), n_faces, body: pos })
}

/// Colour channel order of the vertex properties: indices of red, green, blue[, alpha].
fn colour_slots(h: &Header) -> Option<Vec<usize>> {
    let find = |c: &str| h.vprops.iter().position(|(n, _)| n == c);
    let mut out = vec![find("red")?, find("green")?, find("blue")?];
    if let Some(a) = find("alpha") {
        out.push(a);
    }
    Some(out)
}

fn xyz_slots(h: &Header) -> [usize; 3] {
    let find = |c: &str| h.vprops.iter().position(|(n, _)| n == c).expect("checked");
    [find("x"), find("y"), find("z")]
}

fn split_quads(count: usize, rows: Vec<[i64; 4]>, tris: Vec<[i64; 3]>) -> Vec<[i64; 3]> {
    if count == 3 {
        return tris;
    }
    let mut out = Vec::with_capacity(rows.len() * 2);
    out.extend(rows.iter().map(|q| [q[0], q[1], q[2]]));
    out.extend(rows.iter().map(|q| [q[2], q[3], q[0]]));
    out
}

fn read_binary(data: &[u8], h: &Header) -> Result<PlyMesh, String> {
    let vsize: usize = h.vprops.iter().map(|(_, t)| t.size()).sum();
    let body = &data[h.body..];
    let vbytes = vsize.checked_mul(h.n_vertices).ok_or("too large")?;
    let (ct, it) = h.flist;
    if body.len() < vbytes + ct.size() {
        return fallback("body too short");
    }
    let count = ct.read(&body[vbytes..vbytes + ct.size()], h.big);
    if count != 3.0 && count != 4.0 {
        return fallback("faces are not all triangles or quads");
    }
    let count = count as usize;
    let fsize = ct.size() + count * it.size();
    let fbytes = fsize.checked_mul(h.n_faces).ok_or("too large")?;
    if body.len() != vbytes + fbytes {
        return fallback("body length differs from the header's");
    }
    let offsets: Vec<usize> = h
        .vprops
        .iter()
        .scan(0usize, |o, (_, t)| {
            let here = *o;
            *o += t.size();
            Some(here)
        })
        .collect();
    let [ix, iy, iz] = xyz_slots(h);
    let coord = |row: &[u8], k: usize| {
        let t = h.vprops[k].1;
        t.read(&row[offsets[k]..offsets[k] + t.size()], h.big)
    };
    let mut vertices = Vec::with_capacity(h.n_vertices);
    for row in body[..vbytes].chunks_exact(vsize) {
        vertices.push([coord(row, ix), coord(row, iy), coord(row, iz)]);
    }
    let colors = colour_slots(h).map(|slots| {
        let mut c = Vec::with_capacity(h.n_vertices * slots.len());
        for row in body[..vbytes].chunks_exact(vsize) {
            c.extend(slots.iter().map(|&k| row[offsets[k]]));
        }
        (c, slots.len())
    });
    let mut tris = Vec::new();
    let mut quads = Vec::new();
    if count == 3 {
        tris.reserve(h.n_faces);
    } else {
        quads.reserve(h.n_faces);
    }
    let is = it.size();
    for row in body[vbytes..].chunks_exact(fsize) {
        if ct.read(&row[..ct.size()], h.big) as usize != count {
            return fallback("faces of several sizes");
        }
        let ids = &row[ct.size()..];
        let idx = |j: usize| it.read(&ids[j * is..(j + 1) * is], h.big) as i64;
        if count == 3 {
            tris.push([idx(0), idx(1), idx(2)]);
        } else {
            quads.push([idx(0), idx(1), idx(2), idx(3)]);
        }
    }
    Ok(PlyMesh { vertices, faces: split_quads(count, quads, tris), colors })
}

/// A plain decimal number token (what numpy's text parser and Rust read alike), as f64.
fn number(tok: &str) -> Option<f64> {
    let b = tok.as_bytes();
    let mut i = 0;
    if i < b.len() && (b[i] == b'+' || b[i] == b'-') {
        i += 1;
    }
    let d0 = i;
    while i < b.len() && b[i].is_ascii_digit() {
        i += 1;
    }
    let mut digits = i - d0;
    if i < b.len() && b[i] == b'.' {
        i += 1;
        let f0 = i;
        while i < b.len() && b[i].is_ascii_digit() {
            i += 1;
        }
        digits += i - f0;
    }
    if digits == 0 {
        return None;
    }
    if i < b.len() && (b[i] == b'e' || b[i] == b'E') {
        i += 1;
        if i < b.len() && (b[i] == b'+' || b[i] == b'-') {
            i += 1;
        }
        let e0 = i;
        while i < b.len() && b[i].is_ascii_digit() {
            i += 1;
        }
        if i == e0 || i - e0 > 4 {
            return None;
        }
    }
    if i != b.len() {
        return None;
    }
    tok.parse::<f64>().ok()
}

/// A token of an integer-typed property: digits only (optional sign), within the type's range.
fn integer(tok: &str, t: Ty) -> Option<i64> {
    let digits = tok.strip_prefix(['+', '-']).unwrap_or(tok);
    if digits.is_empty() || digits.len() > 10 || !digits.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    let v: i64 = tok.parse().ok()?;
    let (lo, hi) = t.range();
    (lo <= v && v <= hi).then_some(v)
}

fn ascii_value(tok: &str, t: Ty) -> Option<f64> {
    match t {
        Ty::F32 => number(tok).map(|x| x as f32 as f64),
        Ty::F64 => number(tok),
        _ => integer(tok, t).map(|v| v as f64),
    }
}

fn read_ascii(data: &[u8], h: &Header) -> Result<PlyMesh, String> {
    let body = &data[h.body..];
    // the whole body must be plain text with \n or \r\n line ends (what numpy and we split alike)
    for (k, &c) in body.iter().enumerate() {
        let ok = (b' '..0x7f).contains(&c) || c == b'\n' || c == b'\t' || (c == b'\r' && body.get(k + 1) == Some(&b'\n'));
        if !ok {
            return fallback("bytes other than plain text in the body");
        }
    }
    let text = std::str::from_utf8(body).map_err(|_| "body not text".to_string())?;
    let mut lines = text.split('\n').map(|l| l.strip_suffix('\r').unwrap_or(l));
    let [ix, iy, iz] = xyz_slots(h);
    let slots = colour_slots(h);
    let mut vertices = Vec::with_capacity(h.n_vertices);
    let mut colors: Vec<u8> = Vec::new();
    let mut vals = vec![0.0f64; h.vprops.len()];
    for _ in 0..h.n_vertices {
        let line = lines.next().ok_or("too few lines")?;
        let mut toks = line.split([' ', '\t']).filter(|s| !s.is_empty());
        for (k, (_, t)) in h.vprops.iter().enumerate() {
            let tok = toks.next().ok_or("a short vertex row")?;
            vals[k] = ascii_value(tok, *t).ok_or("a number to guess about")?;
        }
        if toks.next().is_some() {
            return fallback("a long vertex row");
        }
        vertices.push([vals[ix], vals[iy], vals[iz]]);
        if let Some(s) = &slots {
            colors.extend(s.iter().map(|&k| vals[k] as u8));
        }
    }
    let (ct, it) = h.flist;
    let mut count = 0usize;
    let mut tris = Vec::new();
    let mut quads = Vec::new();
    for f in 0..h.n_faces {
        let line = lines.next().ok_or("too few lines")?;
        let toks: Vec<&str> = line.split([' ', '\t']).filter(|s| !s.is_empty()).collect();
        let c = toks.first().and_then(|t| integer(t, ct)).ok_or("a face row without a count")?;
        if f == 0 {
            if c != 3 && c != 4 {
                return fallback("faces are not all triangles or quads");
            }
            count = c as usize;
        }
        if c as usize != count || toks.len() != 1 + count {
            return fallback("faces of several sizes or long rows");
        }
        let mut ids = [0i64; 4];
        for j in 0..count {
            ids[j] = integer(toks[1 + j], it).ok_or("a face index to guess about")?;
        }
        if count == 3 {
            tris.push([ids[0], ids[1], ids[2]]);
        } else {
            quads.push(ids);
        }
    }
    let colors = slots.map(|s| (colors, s.len()));
    Ok(PlyMesh { vertices, faces: split_quads(count, quads, tris), colors })
}

/// Read a PLY file's bytes on the fast path; `Err(reason)` means "read it the general way".
pub fn read_ply(data: &[u8]) -> Result<PlyMesh, String> {
    let h = parse_header(data)?;
    if h.ascii {
        read_ascii(data, &h)
    } else {
        read_binary(data, &h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str = "ply\nformat ascii 1.0\ncomment x\nelement vertex 4\nproperty float x\nproperty float y\n\
                        property double z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n";

    #[test]
    fn ascii_triangles() {
        let s = format!("{HEAD}0 0 0.1\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
        let m = read_ply(s.as_bytes()).unwrap();
        assert_eq!(m.vertices[0], [0.0, 0.0, 0.1]);
        assert_eq!(m.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(m.colors.is_none());
    }

    #[test]
    fn float_properties_are_rounded_to_f32() {
        let s = format!("{HEAD}0.1 0 0.1\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
        let m = read_ply(s.as_bytes()).unwrap();
        assert_eq!(m.vertices[0][0], 0.1f32 as f64);
        assert_eq!(m.vertices[0][2], 0.1);
    }

    #[test]
    fn binary_quads_both_orders() {
        for big in [false, true] {
            let mut b = format!(
                "ply\nformat binary_{}_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
                 property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
                 element face 1\nproperty list uchar int vertex_index\nend_header\n",
                if big { "big" } else { "little" }
            )
            .into_bytes();
            for k in 0..4u8 {
                for x in [k as f32, 1.0, 2.0] {
                    b.extend(if big { x.to_be_bytes() } else { x.to_le_bytes() });
                }
                b.extend([k, 10 + k, 20 + k]);
            }
            b.push(4);
            for i in [0i32, 1, 2, 3] {
                b.extend(if big { i.to_be_bytes() } else { i.to_le_bytes() });
            }
            let m = read_ply(&b).unwrap();
            assert_eq!(m.vertices[3], [3.0, 1.0, 2.0]);
            assert_eq!(m.faces, vec![[0, 1, 2], [2, 3, 0]]);
            let (c, ch) = m.colors.unwrap();
            assert_eq!(ch, 3);
            assert_eq!(&c[9..12], &[3, 13, 23]);
            // one byte more or less: not the fast path
            let mut longer = b.clone();
            longer.push(0);
            assert!(read_ply(&longer).is_err());
            assert!(read_ply(&b[..b.len() - 1]).is_err());
        }
    }

    #[test]
    fn unusual_files_fall_back() {
        let ok = format!("{HEAD}0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
        assert!(read_ply(ok.as_bytes()).is_ok());
        for bad in [
            ok.replace("3 0 2 3", "4 0 2 3 1"),       // mixed sizes
            ok.replace("0 1 0\n", "0 1 0 7\n"),        // a long row
            ok.replace("1 1 0", "1 nan 0"),            // a number to guess about
            ok.replace("1 1 0", "1 0x1 0"),
            ok.replace("comment x", "comment TextureFile a.png"),
            ok.replace("element face 2", "element face 2\nproperty uchar flags"),
            ok.replace("3 0 1 2\n", "3 0 1 2\n\n").replace("3 0 2 3\n", ""), // blank line
            ok.replace("end_header", "end_header junk"),
            ok.replace("element vertex 4", "element vertex 4x"),
            ok[..ok.len() - 4].to_string(), // truncated
        ] {
            assert!(read_ply(bad.as_bytes()).is_err(), "{bad}");
        }
    }
}
