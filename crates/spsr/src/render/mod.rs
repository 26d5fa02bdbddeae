//! Pictures of meshes on the CPU, without a display or a GPU: `spsr render`, the preview of
//! `spsr reconstruct --preview` and `spsr.render` in Python.
//!
//! A software rasteriser (no spec section: this is a viewer, not part of the method):
//!
//! * **Camera** (`camera.rs`): orthographic, fitted per view to the extent of the mesh's
//!   vertices seen from that side, with a 5 % margin, one scale for both axes. The views
//!   assume y is up, as in glTF and most scanned meshes: [`View::Front`] looks along −z
//!   (x to the right), [`View::Side`] along −x (−z to the right, seen from the +x side),
//!   [`View::Top`] along −y (x to the right, −z up, so the front is at the bottom), and
//!   [`View::Iso`] along −(1, 1, 1), from the +x +y +z corner. [`View::All`] puts front,
//!   side, top and iso in a 2 × 2 grid, in that reading order.
//! * **Rasterising** (`raster.rs`): 2 × 2 samples per pixel (1 above 4096² pixels),
//!   triangles binned into screen tiles and the tiles drawn in parallel, each with its own
//!   z-buffer; vertices snapped to 1/256 of a sample and a top-left fill rule, so that
//!   triangles sharing an edge neither overlap nor leave cracks. Every tile draws its
//!   triangles in mesh order and keeps the first of equally deep ones, so the picture does
//!   not depend on the thread count.
//! * **Shading** (`shade.rs`): flat Lambert shading per face with a headlight (light from
//!   the camera) plus ambient light. Faces seen from behind (a triangle counter-clockwise
//!   seen from outside shows its back when the surface is flipped or seen from inside)
//!   get their own colour, [`BACK`]. Surface colours come from the mesh's own colours, from
//!   a per-vertex value through the viridis colour map ([`ColorBy`]), or are [`FRONT`];
//!   [`Highlight::Pieces`] paints every connected piece but the largest in [`HIGHLIGHT`].
//!
//! ```no_run
//! use spsr::render::{render, RenderOptions, View};
//! let mesh = spsr::io::read_mesh("mesh.ply".as_ref())?;
//! let image = render(&mesh, &RenderOptions { view: View::All, ..Default::default() })?;
//! image.write_png("mesh.png".as_ref())?;
//! # Ok::<(), spsr::Error>(())
//! ```

mod camera;
mod encode;
mod raster;
mod shade;

use std::str::FromStr;

use crate::error::Error;
use crate::mesh::Mesh;
use crate::Result;

pub use shade::{colormap, BACK, FRONT, HIGHLIGHT};

/// Largest width or height of a picture, in pixels.
pub const MAX_SIZE: u32 = 16384;

/// The side a mesh is seen from (see the [module documentation](self) for the axes).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum View {
    /// Looking along −z, y up.
    Front,
    /// Looking along −x, y up.
    Side,
    /// Looking along −y, −z up.
    Top,
    /// Looking along −(1, 1, 1), y up.
    #[default]
    Iso,
    /// Front, side, top and iso in a 2 × 2 grid.
    All,
}

impl View {
    /// The views by name, as the command line and Python spell them.
    pub const NAMES: [(&'static str, View); 5] = [
        ("front", View::Front),
        ("side", View::Side),
        ("top", View::Top),
        ("iso", View::Iso),
        ("all", View::All),
    ];
}

impl FromStr for View {
    type Err = Error;

    /// A name of [`View::NAMES`], in any case.
    fn from_str(s: &str) -> Result<Self> {
        View::NAMES
            .iter()
            .find(|(name, _)| name.eq_ignore_ascii_case(s.trim()))
            .map(|&(_, v)| v)
            .ok_or_else(|| Error::invalid("view", s, "one of front, side, top, iso, all"))
    }
}

/// What colours the surface.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum ColorBy {
    /// The mesh's own vertex colours when it has them ([`Mesh::colors`]), else [`FRONT`].
    #[default]
    Auto,
    /// [`FRONT`] everywhere.
    Plain,
    /// The per-vertex density ([`Mesh::density`]) through the colour map.
    Density,
    /// The per-vertex attribute of this name (ASCII case ignored) through the colour map.
    Attribute(String),
}

impl FromStr for ColorBy {
    type Err = Error;

    /// `auto`, `plain`, `density` or `attribute:NAME`.
    fn from_str(s: &str) -> Result<Self> {
        let t = s.trim();
        let bad = || Error::invalid("color", s, "auto, plain, density or attribute:NAME");
        if let Some((kind, name)) = t.split_once(':') {
            return if kind.eq_ignore_ascii_case("attribute") && !name.is_empty() {
                Ok(ColorBy::Attribute(name.to_string()))
            } else {
                Err(bad())
            };
        }
        match t.to_ascii_lowercase().as_str() {
            "auto" => Ok(ColorBy::Auto),
            "plain" => Ok(ColorBy::Plain),
            "density" => Ok(ColorBy::Density),
            _ => Err(bad()),
        }
    }
}

/// What stands out in a contrasting colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Highlight {
    /// Nothing.
    #[default]
    None,
    /// Every connected piece (triangles sharing vertices) except the one of largest area.
    Pieces,
}

impl FromStr for Highlight {
    type Err = Error;

    /// `none` or `pieces`.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "none" => Ok(Highlight::None),
            "pieces" => Ok(Highlight::Pieces),
            _ => Err(Error::invalid("highlight", s, "pieces (or none)")),
        }
    }
}

/// How to draw a mesh.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RenderOptions {
    /// The side the mesh is seen from. Default: [`View::Iso`].
    pub view: View,
    /// Width of the picture in pixels, 1 to [`MAX_SIZE`]. Default 800.
    pub width: u32,
    /// Height of the picture in pixels, 1 to [`MAX_SIZE`]. Default 800.
    pub height: u32,
    /// What colours the surface. Default: [`ColorBy::Auto`].
    pub color: ColorBy,
    /// What stands out. Default: [`Highlight::None`].
    pub highlight: Highlight,
    /// Background colour, RGBA; alpha 0 gives a transparent background. Default: opaque
    /// white.
    pub background: [u8; 4],
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            view: View::Iso,
            width: 800,
            height: 800,
            color: ColorBy::Auto,
            highlight: Highlight::None,
            background: [255; 4],
        }
    }
}

impl RenderOptions {
    /// Checks the picture size.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] (field `size`) for a width or height of 0 or above
    /// [`MAX_SIZE`].
    pub fn validate(&self) -> Result<()> {
        let ok = |n: u32| (1..=MAX_SIZE).contains(&n);
        if ok(self.width) && ok(self.height) {
            Ok(())
        } else {
            Err(Error::invalid(
                "size",
                format!("{}x{}", self.width, self.height),
                format!("a width and height from 1 to {MAX_SIZE} pixels"),
            ))
        }
    }
}

/// A picture: rows from the top, 4 bytes (red, green, blue, alpha) per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 4` bytes, row by row from the top.
    pub rgba: Vec<u8>,
    /// The values mapped to the two ends of the colour map (the 2nd and 98th percentiles),
    /// when the surface is coloured by a per-vertex value.
    pub value_range: Option<[f64; 2]>,
    /// Connected pieces of the mesh, when [`Highlight::Pieces`] was asked for.
    pub pieces: Option<usize>,
}

impl Image {
    /// An image of one colour.
    fn filled(width: u32, height: u32, color: [u8; 4]) -> Self {
        Self {
            width,
            height,
            rgba: color.repeat(width as usize * height as usize),
            value_range: None,
            pieces: None,
        }
    }

    /// The pixel in column `x`, row `y` (from the top).
    ///
    /// # Panics
    /// If the pixel lies outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside the image"
        );
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }

    /// Copies `other` into this image with its top-left corner at (`x`, `y`).
    fn blit(&mut self, other: &Image, x: u32, y: u32) {
        let row = 4 * other.width as usize;
        for r in 0..other.height as usize {
            let at = 4 * ((y as usize + r) * self.width as usize + x as usize);
            self.rgba[at..at + row].copy_from_slice(&other.rgba[r * row..(r + 1) * row]);
        }
    }
}

/// Draws `mesh` as `opts` asks.
///
/// Triangles with a vertex of non-finite coordinates are left out.
///
/// # Errors
/// [`Error::InvalidParameter`] for a bad size (field `size`) or an attribute the mesh does
/// not have (field `color`); [`Error::MissingDensity`] for [`ColorBy::Density`] on a mesh
/// without density; [`Error::InvalidMesh`] for a mesh without triangles or finite vertices,
/// with a triangle referring to a missing vertex, or with a per-vertex array of the wrong
/// length.
pub fn render(mesh: &Mesh, opts: &RenderOptions) -> Result<Image> {
    opts.validate()?;
    check_mesh(mesh)?;
    let (colors, value_range) = shade::vertex_colors(mesh, &opts.color)?;
    let (highlighted, pieces) = match opts.highlight {
        Highlight::None => (None, None),
        Highlight::Pieces => {
            let (flags, pieces) = shade::minor_pieces(mesh);
            (Some(flags), Some(pieces))
        }
    };
    let scene = raster::Scene {
        vertices: &mesh.vertices,
        triangles: &mesh.triangles,
        colors: &colors,
        highlighted: highlighted.as_deref(),
        background: opts.background,
    };
    let (w, h) = (opts.width, opts.height);
    let mut image = match opts.view {
        View::All => {
            let (left, top) = (w.div_ceil(2), h.div_ceil(2));
            let quadrants = [
                (View::Front, 0, 0, left, top),
                (View::Side, left, 0, w - left, top),
                (View::Top, 0, top, left, h - top),
                (View::Iso, left, top, w - left, h - top),
            ];
            let mut image = Image::filled(w, h, opts.background);
            for (view, x, y, qw, qh) in quadrants {
                if qw > 0 && qh > 0 {
                    image.blit(&draw_view(&scene, mesh, view, qw, qh)?, x, y);
                }
            }
            image
        }
        view => draw_view(&scene, mesh, view, w, h)?,
    };
    image.value_range = value_range;
    image.pieces = pieces;
    Ok(image)
}

fn draw_view(
    scene: &raster::Scene<'_>,
    mesh: &Mesh,
    view: View,
    width: u32,
    height: u32,
) -> Result<Image> {
    let camera = camera::Camera::fit(&mesh.vertices, view, width, height).ok_or_else(|| {
        Error::InvalidMesh("no vertex has finite coordinates; there is nothing to draw".into())
    })?;
    Ok(Image {
        width,
        height,
        rgba: raster::draw(scene, &camera),
        value_range: None,
        pieces: None,
    })
}

/// A mesh with triangles, every index in range and fewer triangles than the rasteriser's
/// "no triangle" marker.
fn check_mesh(mesh: &Mesh) -> Result<()> {
    if mesh.triangles.is_empty() {
        return Err(Error::InvalidMesh(
            "the mesh has no triangles; there is nothing to draw".into(),
        ));
    }
    if mesh.triangles.len() >= raster::NO_TRIANGLE as usize {
        return Err(Error::InvalidMesh(format!(
            "the mesh has {} triangles; at most {} can be drawn",
            mesh.triangles.len(),
            raster::NO_TRIANGLE - 1
        )));
    }
    let nv = mesh.vertices.len();
    if let Some((t, tri)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, tri)| tri.iter().any(|&i| i as usize >= nv))
    {
        return Err(Error::InvalidMesh(format!(
            "triangle {t} refers to vertex {tri:?} but there are only {nv} vertices"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
