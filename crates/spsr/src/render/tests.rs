use super::camera::Camera;
use super::*;
use crate::attributes::{Attribute, AttributeData};

/// A UV sphere (poles on the y axis), triangles counter-clockwise seen from outside.
fn sphere(centre: [f64; 3], r: f64, lon: usize, lat: usize) -> Mesh {
    let mut vertices = vec![[centre[0], centre[1] + r, centre[2]]];
    for i in 1..lat {
        let theta = std::f64::consts::PI * i as f64 / lat as f64;
        for j in 0..lon {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / lon as f64;
            vertices.push([
                centre[0] + r * theta.sin() * phi.cos(),
                centre[1] + r * theta.cos(),
                centre[2] + r * theta.sin() * phi.sin(),
            ]);
        }
    }
    vertices.push([centre[0], centre[1] - r, centre[2]]);
    let ring = |i: usize, j: usize| (1 + (i - 1) * lon + j % lon) as u32;
    let south = vertices.len() as u32 - 1;
    let mut triangles = Vec::new();
    for j in 0..lon {
        triangles.push([0, ring(1, j + 1), ring(1, j)]);
        triangles.push([south, ring(lat - 1, j), ring(lat - 1, j + 1)]);
    }
    for i in 1..lat - 1 {
        for j in 0..lon {
            triangles.push([ring(i, j), ring(i, j + 1), ring(i + 1, j)]);
            triangles.push([ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)]);
        }
    }
    let mut mesh = Mesh {
        vertices,
        triangles,
        ..Default::default()
    };
    if mesh.signed_volume() < 0.0 {
        flip(&mut mesh);
    }
    mesh
}

fn flip(mesh: &mut Mesh) {
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
}

/// The axis-aligned box `[lo, hi]`, outward.
fn cuboid(lo: [f64; 3], hi: [f64; 3]) -> Mesh {
    let vertices = (0..8)
        .map(|i| std::array::from_fn(|k| if i >> k & 1 == 1 { hi[k] } else { lo[k] }))
        .collect();
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let mut mesh = Mesh {
        vertices,
        triangles,
        ..Default::default()
    };
    if mesh.signed_volume() < 0.0 {
        flip(&mut mesh);
    }
    mesh
}

fn transparent(view: View, width: u32, height: u32) -> RenderOptions {
    RenderOptions {
        view,
        width,
        height,
        background: [0; 4],
        ..Default::default()
    }
}

/// Compares the picture's coverage (alpha at least one half) with a predicate on pixel
/// centres whose signed distance to the expected outline (negative inside) is `dist`:
/// returns the intersection over union and the number of pixels farther than one pixel
/// from the outline on which they disagree.
fn compare(image: &Image, dist: impl Fn(f64, f64) -> f64) -> (f64, usize) {
    let (mut inter, mut union, mut wrong) = (0usize, 0usize, 0usize);
    for y in 0..image.height {
        for x in 0..image.width {
            let covered = image.pixel(x, y)[3] >= 128;
            let d = dist(x as f64 + 0.5, y as f64 + 0.5);
            let inside = d < 0.0;
            inter += (covered && inside) as usize;
            union += (covered || inside) as usize;
            if d.abs() > 1.0 && covered != inside {
                wrong += 1;
            }
        }
    }
    (inter as f64 / union as f64, wrong)
}

#[test]
fn a_sphere_is_drawn_as_its_projected_disc_in_every_view() {
    let (centre, r) = ([0.3, -1.0, 2.0], 1.7);
    let mesh = sphere(centre, r, 256, 128);
    for view in [View::Front, View::Side, View::Top, View::Iso] {
        let (w, h) = (220, 160);
        let image = render(&mesh, &transparent(view, w, h)).unwrap();
        let camera = Camera::fit(&mesh.vertices, view, w, h).unwrap();
        let [cx, cy, _] = camera.project(centre);
        let radius = r * camera.scale;
        // Fitted: the disc fills the picture's height less the margins.
        assert!(
            (2.0 * radius - 0.9 * h as f64).abs() < 0.5,
            "{view:?}: {radius}"
        );
        assert!(
            (cx - 110.0).abs() < 0.5 && (cy - 80.0).abs() < 0.5,
            "{view:?}"
        );
        let (iou, wrong) = compare(&image, |x, y| (x - cx).hypot(y - cy) - radius);
        assert!(iou > 0.98, "{view:?}: IoU {iou}");
        assert_eq!(
            wrong, 0,
            "{view:?}: pixels clearly inside or outside drawn wrongly"
        );
    }
}

#[test]
fn a_box_seen_from_the_front_is_its_rectangle() {
    let mesh = cuboid([-1.0, 0.0, 5.0], [3.0, 2.0, 9.0]);
    let (w, h) = (300, 200);
    let image = render(&mesh, &transparent(View::Front, w, h)).unwrap();
    // 4 × 2 units: the width limits the scale, 270 pixels for 4 units.
    let camera = Camera::fit(&mesh.vertices, View::Front, w, h).unwrap();
    assert!((camera.scale - 270.0 / 4.0).abs() < 1e-9);
    let [x0, y1, _] = camera.project([-1.0, 0.0, 9.0]);
    let [x1, y0, _] = camera.project([3.0, 2.0, 9.0]);
    assert!((x0 - 15.0).abs() < 1e-9 && (x1 - 285.0).abs() < 1e-9);
    let (iou, wrong) = compare(&image, |x, y| {
        let dx = (x0 - x).max(x - x1);
        let dy = (y0 - y).max(y - y1);
        dx.max(dy)
    });
    assert!(iou > 0.98, "IoU {iou}");
    assert_eq!(wrong, 0);
    // The front face looks straight at the camera: fully lit, the plain colour.
    let expected = FRONT.map(|c| (c * 255.0).round() as u8);
    assert_eq!(image.pixel(150, 100)[..3], expected);
}

/// Red, green and blue channels as floats.
fn rgb(p: [u8; 4]) -> [f32; 3] {
    [p[0] as f32, p[1] as f32, p[2] as f32]
}

/// True when the pixel has the hue of `colour`: a multiple of it within 2 % of full scale.
fn has_hue(p: [u8; 4], colour: [f32; 3]) -> bool {
    let p = rgb(p);
    let s = p.iter().sum::<f32>() / colour.iter().sum::<f32>();
    (0..3).all(|k| (p[k] - s * colour[k]).abs() < 0.02 * 255.0 + 1.0)
}

#[test]
fn faces_seen_from_behind_get_the_back_colour() {
    let mut mesh = sphere([0.0; 3], 1.0, 64, 32);
    let opts = RenderOptions {
        view: View::Front,
        width: 101,
        height: 101,
        ..Default::default()
    };
    let front = render(&mesh, &opts).unwrap().pixel(50, 50);
    assert!(has_hue(front, FRONT), "{front:?}");
    flip(&mut mesh);
    let back = render(&mesh, &opts).unwrap().pixel(50, 50);
    assert!(has_hue(back, BACK), "{back:?}");
    // Headlight: the centre faces the camera, the rim does not.
    let rim = render(&mesh, &opts).unwrap().pixel(50, 7);
    assert!(rgb(rim)[0] < 0.8 * rgb(back)[0], "{rim:?} {back:?}");
}

#[test]
fn highlighting_paints_every_piece_but_the_largest() {
    let mut mesh = sphere([0.0; 3], 1.0, 64, 32);
    let small = cuboid([2.0, -0.2, -0.2], [2.4, 0.2, 0.2]);
    let n = mesh.vertices.len() as u32;
    mesh.vertices.extend(&small.vertices);
    mesh.triangles
        .extend(small.triangles.iter().map(|t| t.map(|i| i + n)));
    let mut opts = RenderOptions {
        view: View::Front,
        width: 340,
        height: 200,
        ..Default::default()
    };
    let camera = Camera::fit(&mesh.vertices, View::Front, 340, 200).unwrap();
    let [sx, sy, _] = camera.project([2.2, 0.0, 0.2]);
    let [bx, by, _] = camera.project([0.0, 0.0, 1.0]);
    let (sx, sy, bx, by) = (sx as u32, sy as u32, bx as u32, by as u32);
    let plain = render(&mesh, &opts).unwrap();
    assert!(plain.pieces.is_none());
    assert!(has_hue(plain.pixel(sx, sy), FRONT));
    opts.highlight = Highlight::Pieces;
    let image = render(&mesh, &opts).unwrap();
    assert_eq!(image.pieces, Some(2));
    assert!(
        has_hue(image.pixel(sx, sy), HIGHLIGHT),
        "{:?}",
        image.pixel(sx, sy)
    );
    assert!(has_hue(image.pixel(bx, by), FRONT));
    let highlighted = image
        .rgba
        .chunks_exact(4)
        .filter(|p| has_hue([p[0], p[1], p[2], p[3]], HIGHLIGHT));
    // The small box's front face: 0.4 × 0.4 units.
    let expected = (0.4 * camera.scale).powi(2);
    let count = highlighted.count() as f64;
    assert!(
        (count - expected).abs() < 0.1 * expected,
        "{count} vs {expected}"
    );
}

#[test]
fn the_colour_map_runs_from_purple_to_yellow() {
    let byte = |c: [f32; 3]| c.map(|v| (v * 255.0).round() as u8);
    assert_eq!(byte(colormap(0.0)), [0x44, 0x01, 0x54]);
    assert_eq!(byte(colormap(1.0)), [0xfd, 0xe7, 0x25]);
    assert_eq!(colormap(-3.0), colormap(0.0));
    assert_eq!(colormap(7.0), colormap(1.0));
    assert_eq!(byte(colormap(f64::NAN)), [128, 128, 128]);
    // Monotonic in lightness (sum of channels) from one end to the other.
    let light = |t: f64| colormap(t).iter().sum::<f32>();
    assert!((0..20).all(|i| light(i as f64 / 20.0) < light((i + 1) as f64 / 20.0)));
}

/// A square facing the front camera, values 0 on its left side and 10 on its right.
fn ramp() -> Mesh {
    Mesh {
        vertices: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.0, 1.0, 0.0],
        ],
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        density: Some(vec![0.0, 10.0, 10.0, 0.0]),
        attributes: vec![Attribute::new(
            "quality",
            AttributeData::U16(vec![0, 10, 10, 0]),
        )],
        ..Default::default()
    }
}

#[test]
fn a_value_is_drawn_through_the_colour_map_between_its_percentiles() {
    let mesh = ramp();
    for color in [ColorBy::Density, ColorBy::Attribute("QUALITY".into())] {
        let opts = RenderOptions {
            view: View::Front,
            width: 100,
            height: 100,
            color,
            ..Default::default()
        };
        let image = render(&mesh, &opts).unwrap();
        assert_eq!(image.value_range, Some([0.0, 10.0]));
        let byte = |c: [f32; 3]| c.map(|v| (v * 255.0).round() as i32);
        let near = |p: [u8; 4], c: [f32; 3]| {
            let e = byte(c);
            (0..3).all(|k| (p[k] as i32 - e[k]).abs() <= 4)
        };
        // The square spans pixels 5 to 95; near its left side t is about 0.006.
        assert!(
            near(image.pixel(5, 50), colormap(0.0)),
            "{:?}",
            image.pixel(5, 50)
        );
        assert!(
            near(image.pixel(94, 50), colormap(1.0)),
            "{:?}",
            image.pixel(94, 50)
        );
        assert!(
            near(image.pixel(50, 50), colormap(0.5)),
            "{:?}",
            image.pixel(50, 50)
        );
    }
}

#[test]
fn the_meshs_own_colours_are_used_by_default() {
    let mut mesh = ramp();
    for (name, v) in [("red", 255u8), ("green", 0), ("blue", 0)] {
        mesh.attributes
            .push(Attribute::new(name, AttributeData::U8(vec![v; 4])));
    }
    let opts = RenderOptions {
        view: View::Front,
        width: 50,
        height: 50,
        ..Default::default()
    };
    assert_eq!(
        render(&mesh, &opts).unwrap().pixel(25, 25),
        [255, 0, 0, 255]
    );
    let plain = RenderOptions {
        color: ColorBy::Plain,
        ..opts
    };
    assert!(has_hue(render(&mesh, &plain).unwrap().pixel(25, 25), FRONT));
}

#[test]
fn all_views_share_one_picture() {
    let mesh = cuboid([0.0; 3], [1.0, 2.0, 3.0]);
    let opts = RenderOptions {
        view: View::All,
        width: 201,
        height: 100,
        ..Default::default()
    };
    let image = render(&mesh, &opts).unwrap();
    assert_eq!(
        (image.width, image.height, image.rgba.len()),
        (201, 100, 201 * 100 * 4)
    );
    // Each quadrant has the box in its middle.
    for (x, y) in [(50, 25), (151, 25), (50, 75), (151, 75)] {
        assert_ne!(image.pixel(x, y), [255; 4], "({x}, {y})");
    }
    // The front quadrant holds exactly the front view at its size.
    let front = render(
        &mesh,
        &RenderOptions {
            view: View::Front,
            width: 101,
            height: 50,
            ..Default::default()
        },
    )
    .unwrap();
    for y in 0..50 {
        for x in 0..101 {
            assert_eq!(image.pixel(x, y), front.pixel(x, y));
        }
    }
}

#[test]
fn the_picture_does_not_depend_on_the_thread_count() {
    // Many small triangles, some sharing depths with others (two coincident spheres).
    let mut mesh = sphere([0.0; 3], 1.0, 300, 150);
    let other = sphere([0.2, 0.0, 0.0], 1.0, 200, 100);
    let n = mesh.vertices.len() as u32;
    mesh.vertices.extend(&other.vertices);
    mesh.triangles
        .extend(other.triangles.iter().map(|t| t.map(|i| i + n)));
    let opts = RenderOptions {
        view: View::Iso,
        width: 257,
        height: 190,
        highlight: Highlight::Pieces,
        ..Default::default()
    };
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| render(&mesh, &opts).unwrap())
    };
    let one = run(1);
    assert_eq!(one, run(4));
    assert_eq!(one, run(3));
}

#[test]
fn shared_edges_leave_no_cracks() {
    // A fan of thin triangles around the centre of the picture: every sample inside the
    // disc they tile belongs to exactly one of them.
    let n = 997;
    let mut vertices = vec![[0.0, 0.0, 0.0]];
    for i in 0..n {
        let a = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
        vertices.push([a.cos(), a.sin(), 0.0]);
    }
    let triangles = (0..n as u32)
        .map(|i| [0, 1 + i, 1 + (i + 1) % n as u32])
        .collect();
    let mesh = Mesh {
        vertices,
        triangles,
        ..Default::default()
    };
    let image = render(&mesh, &transparent(View::Front, 120, 120)).unwrap();
    for y in 30..90 {
        for x in 30..90 {
            assert_eq!(image.pixel(x, y)[3], 255, "({x}, {y})");
        }
    }
}

#[test]
fn bad_requests_are_errors() {
    let mesh = cuboid([0.0; 3], [1.0; 3]);
    let size = |width, height| RenderOptions {
        width,
        height,
        ..Default::default()
    };
    for (w, h) in [(0, 10), (10, 0), (MAX_SIZE + 1, 10)] {
        let e = render(&mesh, &size(w, h)).unwrap_err();
        assert!(
            matches!(e, Error::InvalidParameter { field: "size", .. }),
            "{e}"
        );
        assert!(e.to_string().contains(&format!("{w}x{h}")), "{e}");
    }
    let empty = Mesh {
        vertices: mesh.vertices.clone(),
        ..Default::default()
    };
    let e = render(&empty, &RenderOptions::default()).unwrap_err();
    assert!(e.to_string().contains("no triangles"), "{e}");
    let mut broken = mesh.clone();
    broken.triangles.push([0, 1, 8]);
    let e = render(&broken, &RenderOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("triangle 12 refers to vertex"),
        "{e}"
    );
    let mut nowhere = mesh.clone();
    nowhere.vertices = vec![[f64::NAN; 3]; 8];
    assert!(matches!(
        render(&nowhere, &RenderOptions::default()),
        Err(Error::InvalidMesh(_))
    ));

    let color = |c: ColorBy| RenderOptions {
        color: c,
        ..Default::default()
    };
    assert!(matches!(
        render(&mesh, &color(ColorBy::Density)),
        Err(Error::MissingDensity)
    ));
    let e = render(&ramp(), &color(ColorBy::Attribute("intensity".into()))).unwrap_err();
    assert_eq!(
        e.to_string(),
        "invalid parameter color = the attribute 'intensity': expected a per-vertex \
         attribute the mesh has (it has: quality)"
    );
    let mut short = ramp();
    short.density = Some(vec![1.0]);
    let e = render(&short, &color(ColorBy::Density)).unwrap_err();
    assert!(e.to_string().contains("1 values for 4 vertices"), "{e}");
}

#[test]
fn a_vertex_that_is_not_finite_drops_its_triangles_only() {
    let mut mesh = ramp();
    mesh.vertices.push([f64::INFINITY, 0.0, 0.0]);
    mesh.triangles.push([0, 1, 4]);
    let opts = transparent(View::Front, 60, 60);
    assert_eq!(
        render(&mesh, &opts).unwrap().rgba,
        render(&ramp(), &opts).unwrap().rgba
    );
}

/// A triangle reaching a vertex at infinity must not take the largest piece's area away, or
/// the whole surface would be highlighted instead of the fragment.
#[test]
fn a_vertex_that_is_not_finite_does_not_change_which_piece_is_largest() {
    // The small box first, so that the sphere must win the comparison of areas.
    let mut mesh = cuboid([2.0, -0.2, -0.2], [2.4, 0.2, 0.2]);
    let ball = sphere([0.0; 3], 1.0, 64, 32);
    let n = mesh.vertices.len() as u32;
    mesh.vertices.extend(&ball.vertices);
    mesh.triangles
        .extend(ball.triangles.iter().map(|t| t.map(|i| i + n)));
    mesh.vertices.push([f64::NAN, 0.0, 0.0]);
    let nan = mesh.vertices.len() as u32 - 1;
    mesh.triangles.push([n, n + 1, nan]);
    let opts = RenderOptions {
        view: View::Front,
        width: 340,
        height: 200,
        highlight: Highlight::Pieces,
        ..Default::default()
    };
    let camera = Camera::fit(&mesh.vertices, View::Front, 340, 200).unwrap();
    let [sx, sy, _] = camera.project([2.2, 0.0, 0.2]);
    let [bx, by, _] = camera.project([0.0, 0.0, 1.0]);
    let image = render(&mesh, &opts).unwrap();
    assert_eq!(image.pieces, Some(2));
    assert!(has_hue(image.pixel(sx as u32, sy as u32), HIGHLIGHT));
    assert!(has_hue(image.pixel(bx as u32, by as u32), FRONT));
}

#[test]
fn names_parse_as_the_command_line_spells_them() {
    assert_eq!("ISO".parse::<View>().unwrap(), View::Iso);
    assert_eq!("all".parse::<View>().unwrap(), View::All);
    assert!("back".parse::<View>().is_err());
    assert_eq!("density".parse::<ColorBy>().unwrap(), ColorBy::Density);
    assert_eq!(
        "attribute:quality".parse::<ColorBy>().unwrap(),
        ColorBy::Attribute("quality".into())
    );
    for bad in ["attribute:", "attribute", "quality", "colour:red"] {
        let e = bad.parse::<ColorBy>().unwrap_err();
        assert!(
            matches!(e, Error::InvalidParameter { field: "color", .. }),
            "{bad}"
        );
    }
    assert_eq!("pieces".parse::<Highlight>().unwrap(), Highlight::Pieces);
    assert!("holes".parse::<Highlight>().is_err());
}

#[test]
fn pictures_are_written_as_png() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("box.png");
    let mesh = cuboid([0.0; 3], [1.0; 3]);
    for background in [[255; 4], [0; 4]] {
        let image = render(
            &mesh,
            &RenderOptions {
                width: 64,
                height: 48,
                background,
                ..Default::default()
            },
        )
        .unwrap();
        image.write_png(&path).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (64, 48));
        let rgba: Vec<u8> = match info.color_type {
            png::ColorType::Rgb => buf
                .chunks_exact(3)
                .flat_map(|p| [p[0], p[1], p[2], 255])
                .collect(),
            png::ColorType::Rgba => buf[..64 * 48 * 4].to_vec(),
            other => panic!("{other:?}"),
        };
        assert_eq!(rgba, image.rgba);
    }
    let e = render(&mesh, &RenderOptions::default())
        .unwrap()
        .write_png(&dir.path().join("missing/box.png"))
        .unwrap_err();
    assert!(matches!(e, Error::Output { .. }), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}
