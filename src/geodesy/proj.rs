//! The few functions of the PROJ C library (Debian's `libproj-dev`, linked by `build.rs`) that
//! bimtiles uses, behind safe owners that free what PROJ allocates: a [`Context`] (one per
//! thread: PROJ contexts are not shared between threads), CRS and operation objects ([`Object`]).
//! A context keeps the CRSs it made from text and the operations it chose to WGS 84, because
//! each of them is a query of PROJ's database, and reading one model asks for the same CRS
//! several times (is it known, its unit, its place, its vertices).
//!
//! Only what placing a model needs is declared: creating a CRS from a name or code, its type, its
//! axes' unit, its area of use, a CRS-to-CRS operation normalized to easting/northing and
//! longitude/latitude order, the operation PROJ actually used and its accuracy.

use std::cell::RefCell;
use std::collections::HashMap;
use std::ffi::{c_char, c_double, c_int, c_void, CStr, CString};
use std::ptr::{null, null_mut};

#[repr(C)]
struct PjContext {
    _private: [u8; 0],
}
#[repr(C)]
struct Pj {
    _private: [u8; 0],
}

/// `PJ_COORD`: a union of four doubles; every member is laid out as `[f64; 4]`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
struct PjCoord {
    v: [c_double; 4],
}

#[repr(C)]
struct PjProjInfo {
    id: *const c_char,
    description: *const c_char,
    definition: *const c_char,
    has_inverse: c_int,
    accuracy: c_double,
}

const PJ_FWD: c_int = 1;
const PJ_LOG_NONE: c_int = 0;
/// `PJ_COMPARISON_CRITERION`: same objects, names and identifiers included.
const PJ_COMP_STRICT: c_int = 0;

/// `PJ_TYPE` values used here (proj.h, PROJ 9).
pub const PJ_TYPE_GEOGRAPHIC_2D_CRS: i32 = 12;
pub const PJ_TYPE_GEOGRAPHIC_3D_CRS: i32 = 13;
pub const PJ_TYPE_VERTICAL_CRS: i32 = 14;
pub const PJ_TYPE_PROJECTED_CRS: i32 = 15;
pub const PJ_TYPE_COMPOUND_CRS: i32 = 16;
pub const PJ_TYPE_BOUND_CRS: i32 = 19;

#[link(name = "proj")]
extern "C" {
    fn proj_context_create() -> *mut PjContext;
    fn proj_context_destroy(ctx: *mut PjContext) -> *mut PjContext;
    fn proj_log_level(ctx: *mut PjContext, level: c_int) -> c_int;
    fn proj_context_errno(ctx: *mut PjContext) -> c_int;
    fn proj_context_errno_string(ctx: *mut PjContext, err: c_int) -> *const c_char;
    fn proj_create(ctx: *mut PjContext, definition: *const c_char) -> *mut Pj;
    fn proj_destroy(p: *mut Pj) -> *mut Pj;
    fn proj_is_equivalent_to(a: *const Pj, b: *const Pj, criterion: c_int) -> c_int;
    fn proj_get_type(p: *const Pj) -> c_int;
    fn proj_get_name(p: *const Pj) -> *const c_char;
    fn proj_get_id_auth_name(p: *const Pj, index: c_int) -> *const c_char;
    fn proj_get_id_code(p: *const Pj, index: c_int) -> *const c_char;
    fn proj_crs_get_sub_crs(ctx: *mut PjContext, crs: *const Pj, index: c_int) -> *mut Pj;
    fn proj_crs_get_coordinate_system(ctx: *mut PjContext, crs: *const Pj) -> *mut Pj;
    fn proj_cs_get_axis_count(ctx: *mut PjContext, cs: *const Pj) -> c_int;
    #[allow(clippy::too_many_arguments)]
    fn proj_cs_get_axis_info(
        ctx: *mut PjContext,
        cs: *const Pj,
        index: c_int,
        out_name: *mut *const c_char,
        out_abbrev: *mut *const c_char,
        out_direction: *mut *const c_char,
        out_unit_conv_factor: *mut c_double,
        out_unit_name: *mut *const c_char,
        out_unit_auth_name: *mut *const c_char,
        out_unit_code: *mut *const c_char,
    ) -> c_int;
    fn proj_get_area_of_use(
        ctx: *mut PjContext,
        p: *const Pj,
        west: *mut c_double,
        south: *mut c_double,
        east: *mut c_double,
        north: *mut c_double,
        area_name: *mut *const c_char,
    ) -> c_int;
    fn proj_create_crs_to_crs_from_pj(
        ctx: *mut PjContext,
        source: *const Pj,
        target: *const Pj,
        area: *mut c_void,
        options: *const *const c_char,
    ) -> *mut Pj;
    fn proj_normalize_for_visualization(ctx: *mut PjContext, p: *const Pj) -> *mut Pj;
    fn proj_trans(p: *mut Pj, direction: c_int, coord: PjCoord) -> PjCoord;
    fn proj_trans_get_last_used_operation(p: *mut Pj) -> *mut Pj;
    fn proj_pj_info(p: *mut Pj) -> PjProjInfo;
    fn proj_coordoperation_get_accuracy(ctx: *mut PjContext, op: *const Pj) -> c_double;
    fn proj_errno(p: *const Pj) -> c_int;
    fn proj_errno_reset(p: *const Pj) -> c_int;
}

/// What PROJ said went wrong (its own message: PROJ reports errors as text and a code).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ProjError {
    pub message: String,
}

impl ProjError {
    fn new(message: String) -> Self {
        ProjError { message }
    }
}

fn text(p: *const c_char) -> Option<String> {
    // SAFETY: PROJ returns null or a NUL-terminated string that lives as long as its owner,
    // which the caller holds for the duration of this call.
    (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
}

/// A PROJ context: owns the objects made in it (they must not outlive it, so they borrow it).
pub struct Context {
    ptr: *mut PjContext,
    /// [`Context::create`]'s results by definition, failures too.
    made: RefCell<HashMap<String, Result<*mut Pj, ProjError>>>,
    /// [`Object::sub_crs`] of kept objects, by (object, index).
    parts: RefCell<HashMap<(usize, i32), *mut Pj>>,
    /// [`Context::operation_to_wgs84`] of kept objects: (source, operation). Looked up by
    /// equivalence, not by pointer, because the horizontal part of a compound CRS is another
    /// object than the same CRS made from its code, and each search of operations is a round of
    /// database queries.
    to_wgs84: RefCell<Vec<(*mut Pj, *mut Pj)>>,
}

impl Context {
    /// A new context that logs nothing (errors are returned, not printed).
    pub fn new() -> Option<Context> {
        // SAFETY: plain constructor; null means out of memory.
        let ptr = unsafe { proj_context_create() };
        if ptr.is_null() {
            return None;
        }
        // SAFETY: ptr is a live context.
        unsafe { proj_log_level(ptr, PJ_LOG_NONE) };
        Some(Context {
            ptr,
            made: RefCell::default(),
            parts: RefCell::default(),
            to_wgs84: RefCell::default(),
        })
    }

    /// The text of the context's last error.
    fn last_error(&self) -> String {
        // SAFETY: live context; the string is static or owned by the context.
        let code = unsafe { proj_context_errno(self.ptr) };
        let msg = text(unsafe { proj_context_errno_string(self.ptr, code) });
        msg.unwrap_or_else(|| format!("PROJ error {code}"))
    }

    fn wrap(&self, ptr: *mut Pj) -> Result<Object<'_>, ProjError> {
        if ptr.is_null() {
            Err(ProjError::new(self.last_error()))
        } else {
            Ok(Object {
                ctx: self,
                ptr,
                kept: false,
            })
        }
    }

    /// A handle on an object the context keeps (not freed on drop).
    fn kept(&self, ptr: *mut Pj) -> Object<'_> {
        Object {
            ctx: self,
            ptr,
            kept: true,
        }
    }

    /// Makes an object with `make` once per `key` of `cache` and keeps it for the context's life.
    fn keep<'s, K: std::hash::Hash + Eq>(
        &'s self,
        cache: &RefCell<HashMap<K, *mut Pj>>,
        key: K,
        make: impl FnOnce() -> Result<Object<'s>, ProjError>,
    ) -> Result<Object<'s>, ProjError> {
        if let Some(&ptr) = cache.borrow().get(&key) {
            return Ok(self.kept(ptr));
        }
        let mut made = make()?;
        made.kept = true;
        cache.borrow_mut().insert(key, made.ptr);
        Ok(made)
    }

    /// A CRS (or any object) from a definition PROJ understands: "EPSG:28992", a CRS name such
    /// as "WGS 84 / UTM zone 32N", a WKT or PROJJSON text. Kept: the same definition gives the
    /// same object.
    pub fn create(&self, definition: &str) -> Result<Object<'_>, ProjError> {
        if let Some(made) = self.made.borrow().get(definition) {
            return made.clone().map(|ptr| self.kept(ptr));
        }
        let c = CString::new(definition)
            .map_err(|_| ProjError::new("the name holds a NUL byte".into()))?;
        // SAFETY: live context and a NUL-terminated string.
        let made = self
            .wrap(unsafe { proj_create(self.ptr, c.as_ptr()) })
            .map(|mut object| {
                object.kept = true;
                object
            });
        self.made.borrow_mut().insert(
            definition.to_string(),
            made.as_ref().map(|o| o.ptr).map_err(Clone::clone),
        );
        made
    }

    /// The operation from `source` to `target` that PROJ chooses (by area of use and
    /// accuracy), normalized so that projected CRSs take easting, northing and geographic ones
    /// longitude, latitude (degrees), whatever the CRSs' own axis order.
    pub fn operation(
        &self,
        source: &Object<'_>,
        target: &Object<'_>,
    ) -> Result<Object<'_>, ProjError> {
        // SAFETY: live context and objects of it; null area and options are allowed.
        let op = self.wrap(unsafe {
            proj_create_crs_to_crs_from_pj(self.ptr, source.ptr, target.ptr, null_mut(), null())
        })?;
        // SAFETY: as above.
        self.wrap(unsafe { proj_normalize_for_visualization(self.ptr, op.ptr) })
    }

    /// The operation from `source` to WGS 84 longitude, latitude (degrees), as [`Self::operation`].
    pub fn operation_to_wgs84(&self, source: &Object<'_>) -> Result<Object<'_>, ProjError> {
        let make = || {
            let wgs84 = self.create("EPSG:4326")?;
            self.operation(source, &wgs84)
        };
        if !source.kept {
            return make();
        }
        let known = self.to_wgs84.borrow().iter().find_map(|&(crs, op)| {
            // SAFETY: both are live objects of this context; comparing reads them only.
            let same = crs == source.ptr
                || unsafe { proj_is_equivalent_to(crs, source.ptr, PJ_COMP_STRICT) } != 0;
            same.then_some(op)
        });
        if let Some(op) = known {
            return Ok(self.kept(op));
        }
        let mut op = make()?;
        op.kept = true;
        self.to_wgs84.borrow_mut().push((source.ptr, op.ptr));
        Ok(op)
    }
}

impl Drop for Context {
    fn drop(&mut self) {
        let made = self.made.get_mut().drain().filter_map(|(_, m)| m.ok());
        let parts = self.parts.get_mut().drain().map(|(_, p)| p);
        let ops = self.to_wgs84.get_mut().drain(..).map(|(_, op)| op);
        for ptr in made.chain(parts).chain(ops).collect::<Vec<_>>() {
            // SAFETY: kept objects are owned by the context alone, each destroyed once.
            unsafe { proj_destroy(ptr) };
        }
        // SAFETY: every object borrowed the context and is dropped first.
        unsafe { proj_context_destroy(self.ptr) };
    }
}

/// A PROJ object (CRS, coordinate system or operation), freed on drop unless its context keeps
/// it.
pub struct Object<'c> {
    ctx: &'c Context,
    ptr: *mut Pj,
    kept: bool,
}

impl Drop for Object<'_> {
    fn drop(&mut self) {
        if !self.kept {
            // SAFETY: owned pointer, destroyed once.
            unsafe { proj_destroy(self.ptr) };
        }
    }
}

/// One axis of a coordinate system: its name, direction and unit.
#[derive(Debug, Clone, PartialEq)]
pub struct AxisInfo {
    pub name: String,
    pub direction: String,
    pub unit_name: String,
    /// Metres (or radians) per unit.
    pub unit_to_si: f64,
}

/// Longitude/latitude box (degrees) where a CRS or operation is meant to be used.
#[derive(Debug, Clone, PartialEq)]
pub struct AreaOfUse {
    pub west_deg: f64,
    pub south_deg: f64,
    pub east_deg: f64,
    pub north_deg: f64,
    pub name: String,
}

impl<'c> Object<'c> {
    /// `PJ_TYPE` (see the constants).
    pub fn kind(&self) -> i32 {
        // SAFETY: live object.
        unsafe { proj_get_type(self.ptr) }
    }

    pub fn name(&self) -> String {
        // SAFETY: live object; the string is owned by it.
        text(unsafe { proj_get_name(self.ptr) }).unwrap_or_default()
    }

    /// "EPSG:28992" when the object carries an identifier.
    pub fn id(&self) -> Option<String> {
        // SAFETY: live object; strings owned by it.
        let auth = text(unsafe { proj_get_id_auth_name(self.ptr, 0) })?;
        let code = text(unsafe { proj_get_id_code(self.ptr, 0) })?;
        Some(format!("{auth}:{code}"))
    }

    /// Component `index` of a compound CRS (0: horizontal, 1: vertical).
    pub fn sub_crs(&self, index: i32) -> Result<Object<'c>, ProjError> {
        // SAFETY: live context and object.
        let make = || {
            self.ctx
                .wrap(unsafe { proj_crs_get_sub_crs(self.ctx.ptr, self.ptr, index) })
        };
        if self.kept {
            self.ctx
                .keep(&self.ctx.parts, (self.ptr as usize, index), make)
        } else {
            make()
        }
    }

    /// The axes of this CRS's coordinate system.
    pub fn axes(&self) -> Result<Vec<AxisInfo>, ProjError> {
        // SAFETY: live context and object.
        let cs = self
            .ctx
            .wrap(unsafe { proj_crs_get_coordinate_system(self.ctx.ptr, self.ptr) })?;
        // SAFETY: live coordinate system.
        let n = unsafe { proj_cs_get_axis_count(self.ctx.ptr, cs.ptr) };
        let mut out = Vec::new();
        for i in 0..n.max(0) {
            let (mut name, mut direction, mut unit_name) = (null(), null(), null());
            let mut factor = 0.0;
            // SAFETY: every out pointer is valid; null ones are skipped by PROJ.
            let ok = unsafe {
                proj_cs_get_axis_info(
                    self.ctx.ptr,
                    cs.ptr,
                    i,
                    &mut name,
                    null_mut(),
                    &mut direction,
                    &mut factor,
                    &mut unit_name,
                    null_mut(),
                    null_mut(),
                )
            };
            if ok == 0 {
                return Err(ProjError::new(self.ctx.last_error()));
            }
            out.push(AxisInfo {
                name: text(name).unwrap_or_default(),
                direction: text(direction).unwrap_or_default(),
                unit_name: text(unit_name).unwrap_or_default(),
                unit_to_si: factor,
            });
        }
        Ok(out)
    }

    /// Where the object is meant to be used, if PROJ knows.
    pub fn area_of_use(&self) -> Option<AreaOfUse> {
        let (mut w, mut s, mut e, mut n) = (0.0, 0.0, 0.0, 0.0);
        let mut name = null();
        // SAFETY: live context and object, valid out pointers.
        let ok = unsafe {
            proj_get_area_of_use(
                self.ctx.ptr,
                self.ptr,
                &mut w,
                &mut s,
                &mut e,
                &mut n,
                &mut name,
            )
        };
        (ok != 0 && w > -1000.0).then(|| AreaOfUse {
            west_deg: w,
            south_deg: s,
            east_deg: e,
            north_deg: n,
            name: text(name).unwrap_or_default(),
        })
    }

    /// Applies an operation forward to (x, y, z); an error when PROJ fails or returns
    /// non-finite values.
    pub fn forward(&self, x: f64, y: f64, z: f64) -> Result<[f64; 3], ProjError> {
        // SAFETY: live operation.
        unsafe { proj_errno_reset(self.ptr) };
        let c = PjCoord {
            v: [x, y, z, f64::INFINITY],
        };
        // SAFETY: live operation, plain-data coordinate.
        let r = unsafe { proj_trans(self.ptr, PJ_FWD, c) };
        // SAFETY: live operation.
        let err = unsafe { proj_errno(self.ptr) };
        let p = [r.v[0], r.v[1], r.v[2]];
        if err != 0 || p.iter().any(|v| !v.is_finite()) {
            return Err(ProjError::new(format!(
                "PROJ cannot transform ({x}, {y}): {}",
                self.ctx.last_error()
            )));
        }
        Ok(p)
    }

    /// The operation PROJ last used in [`Object::forward`] (an operation built by
    /// [`Context::operation`] may choose among several by location): its description and its
    /// accuracy in metres (`None` when unknown).
    pub fn last_used(&self) -> Option<(String, Option<f64>)> {
        // SAFETY: live operation; the result is a new object we own.
        let op = self
            .ctx
            .wrap(unsafe { proj_trans_get_last_used_operation(self.ptr) })
            .ok()?;
        // SAFETY: live object; the strings belong to it and are copied at once.
        let info = unsafe { proj_pj_info(op.ptr) };
        let description = text(info.description)
            .or_else(|| text(info.id))
            .unwrap_or_else(|| op.name());
        // SAFETY: live context and operation.
        let accuracy = unsafe { proj_coordoperation_get_accuracy(self.ctx.ptr, op.ptr) };
        Some((description, (accuracy >= 0.0).then_some(accuracy)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn creates_crs_and_reports_errors() {
        let ctx = Context::new().unwrap();
        let rd = ctx.create("EPSG:28992").unwrap();
        assert_eq!(rd.kind(), PJ_TYPE_PROJECTED_CRS);
        assert_eq!(rd.name(), "Amersfoort / RD New");
        assert_eq!(rd.id().as_deref(), Some("EPSG:28992"));
        let axes = rd.axes().unwrap();
        assert_eq!(axes.len(), 2);
        assert_eq!(axes[0].unit_to_si, 1.0);
        let area = rd.area_of_use().unwrap();
        assert!(area.west_deg < 5.0 && area.east_deg > 6.0, "{area:?}");
        assert!(ctx.create("EPSG:99999").is_err());
        let wgs84 = ctx.create("EPSG:4326").unwrap();
        assert_eq!(wgs84.kind(), PJ_TYPE_GEOGRAPHIC_2D_CRS);
        let op = ctx.operation(&rd, &wgs84).unwrap();
        // The Amersfoort tower, RD's origin point (155000, 463000): 5.3872° E, 52.1552° N.
        let p = op.forward(155_000.0, 463_000.0, 0.0).unwrap();
        assert!(
            (p[0] - 5.3872).abs() < 1e-3 && (p[1] - 52.1552).abs() < 1e-3,
            "{p:?}"
        );
        let (desc, acc) = op.last_used().unwrap();
        assert!(desc.contains("RD New"), "{desc}");
        assert!(acc.is_some_and(|a| a > 0.0 && a < 10.0), "{acc:?}");
        assert!(op.forward(f64::NAN, 0.0, 0.0).is_err());
    }

    #[test]
    fn a_compound_s_horizontal_part_shares_the_operation_of_its_crs() {
        let ctx = Context::new().unwrap();
        let utm = ctx.create("EPSG:25832").unwrap();
        let compound = ctx.create("EPSG:25832+7837").unwrap();
        let horizontal = compound.sub_crs(0).unwrap();
        assert_ne!(utm.ptr, horizontal.ptr);
        let a = ctx.operation_to_wgs84(&utm).unwrap().ptr;
        let b = ctx.operation_to_wgs84(&horizontal).unwrap().ptr;
        assert_eq!(a, b);
        // Another CRS gets its own.
        let rd = ctx.create("EPSG:28992").unwrap();
        assert_ne!(ctx.operation_to_wgs84(&rd).unwrap().ptr, a);
        assert_eq!(ctx.to_wgs84.borrow().len(), 2);
    }
}
