//! A coordinate reference system as datasets and outputs carry it: an EPSG code when there is one, its OGC WKT1
//! (for LAS's `LASF_Projection` record and PLY comments) and its PROJ.4 definition (for [`super::Projector`]).
//!
//! Accepted spellings of `transforms.json`'s `crs` and of `--crs`:
//! - `EPSG:32650` (any case; also `urn:ogc:def:crs:EPSG::32650` and a bare `32650`);
//! - OGC WKT (WKT1 `PROJCS[...]`, `GEOGCS[...]`, `COMPD_CS[...]` or WKT2 `PROJCRS[...]`, ...): kept as given; its
//!   top-level `AUTHORITY["EPSG","n"]` / `ID["EPSG",n]` gives the code;
//! - OpenDroneMap's `coords.txt` form `WGS84 UTM 32N` (WGS 84 UTM zones: EPSG 326zz north, 327zz south);
//! - a PROJ string for WGS 84 UTM (`+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs`, `+south`), as ODM's
//!   `gcp_list.txt` headers carry it.

use super::error::CrsError;

/// What the coordinates are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum CrsKind {
    /// Easting, northing (and height): the only kind a dataset's world frame may be in.
    Projected,
    /// Latitude and longitude in degrees.
    Geographic,
    /// Earth-centred, earth-fixed metres (EPSG:4978).
    Geocentric,
}

impl CrsKind {
    pub fn name(self) -> &'static str {
        match self {
            CrsKind::Projected => "projected",
            CrsKind::Geographic => "geographic",
            CrsKind::Geocentric => "geocentric",
        }
    }
}

/// A coordinate reference system.
#[derive(Debug, Clone, PartialEq)]
pub struct Crs {
    pub epsg: Option<u32>,
    /// OGC WKT (WKT1 from the EPSG table, or the text given).
    pub wkt: String,
    /// PROJ.4 definition when the EPSG table has the code (needed to project coordinates into this CRS).
    pub proj4: Option<String>,
    /// The CRS's name (the WKT's first quoted string).
    pub name: String,
    pub kind: CrsKind,
}

/// EPSG:4978 as GDAL writes it in WKT1.
const WGS84_GEOCENTRIC_WKT: &str = r#"GEOCCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AXIS["Geocentric X",OTHER],AXIS["Geocentric Y",OTHER],AXIS["Geocentric Z",NORTH],AUTHORITY["EPSG","4978"]]"#;

const WKT_ROOTS: [&str; 14] = [
    "PROJCS[",
    "GEOGCS[",
    "GEOCCS[",
    "COMPD_CS[",
    "PROJCRS[",
    "GEOGCRS[",
    "GEODCRS[",
    "GEODETICCRS[",
    "PROJECTEDCRS[",
    "COMPOUNDCRS[",
    "BOUNDCRS[",
    "BASEGEOGCRS[",
    "GEOGRAPHICCRS[",
    "VERT_CS[",
];

impl Crs {
    /// Parses any accepted spelling (module doc).
    pub fn parse(text: &str) -> Result<Crs, CrsError> {
        let t = text.trim();
        if t.is_empty() {
            return Err(CrsError::invalid(text, "empty"));
        }
        let upper = t.to_ascii_uppercase();
        if WKT_ROOTS.iter().any(|r| upper.starts_with(r)) {
            return Self::from_wkt(t);
        }
        if let Some(code) = upper.strip_prefix("EPSG:").or_else(|| upper.strip_prefix("URN:OGC:DEF:CRS:EPSG::")) {
            let code = code.trim().parse::<u32>().map_err(|_| CrsError::invalid(text, "not an EPSG code number"))?;
            return Self::from_epsg(code).map_err(|e| match e {
                CrsError::Invalid { reason, .. } => CrsError::invalid(text, reason),
                e => e,
            });
        }
        if let Ok(code) = t.parse::<u32>() {
            return Self::from_epsg(code);
        }
        if let Some(code) = odm_utm(&upper) {
            return Self::from_epsg(code);
        }
        if upper.starts_with("+PROJ=") {
            return proj_utm(&upper).map_err(|r| CrsError::invalid(text, r)).and_then(Self::from_epsg);
        }
        Err(CrsError::invalid(
            text,
            "not an EPSG code (EPSG:32650), OGC WKT (PROJCS[...]), a WGS84 UTM zone (WGS84 UTM 50N) or a PROJ UTM \
             string (+proj=utm +zone=50 +datum=WGS84)",
        ))
    }

    /// The CRS with EPSG code `code`, from the EPSG table (plus WGS 84 geocentric, EPSG:4978, which the table
    /// lacks and Metashape's georeferenced chunks use).
    pub fn from_epsg(code: u32) -> Result<Crs, CrsError> {
        if code == 4978 {
            return Ok(Crs {
                epsg: Some(4978),
                wkt: WGS84_GEOCENTRIC_WKT.into(),
                proj4: Some("+proj=geocent +datum=WGS84 +units=m +no_defs".into()),
                name: "WGS 84".into(),
                kind: CrsKind::Geocentric,
            });
        }
        let def = u16::try_from(code).ok().and_then(crs_definitions::from_code).ok_or_else(|| {
            CrsError::invalid(
                &format!("EPSG:{code}"),
                "not in the EPSG table msnerf carries (crs-definitions); give the CRS as OGC WKT instead",
            )
        })?;
        let proj4 = def.proj4.trim().to_string();
        let kind = if proj4.contains("+proj=longlat") || proj4.contains("+proj=latlong") {
            CrsKind::Geographic
        } else if proj4.contains("+proj=geocent") {
            CrsKind::Geocentric
        } else {
            CrsKind::Projected
        };
        Ok(Crs { epsg: Some(code), wkt: def.wkt.to_string(), proj4: Some(proj4), name: wkt_name(def.wkt), kind })
    }

    fn from_wkt(t: &str) -> Result<Crs, CrsError> {
        let depth_ok = t.chars().try_fold(0i32, |d, c| {
            let d = d + i32::from(c == '[') - i32::from(c == ']');
            (d >= 0).then_some(d)
        });
        if depth_ok != Some(0) {
            return Err(CrsError::invalid(t, "WKT brackets do not balance"));
        }
        let root = wkt::parse(t).map_err(|reason| CrsError::invalid(t, reason))?;
        let kind = wkt_kind(&root).map_err(|reason| CrsError::invalid(t, reason))?;
        let epsg = top_level_epsg(t);
        // The EPSG code at the top must be a CRS of the kind the WKT describes (a PROJCS carrying 4326 would pass
        // the geographic refusal and project nothing).
        if let Some(code) = epsg {
            if let Ok(known) = Self::from_epsg(code) {
                if known.kind != kind {
                    return Err(CrsError::invalid(
                        t,
                        format!(
                            "the WKT describes a {} CRS but its EPSG code {code} is {} ({})",
                            kind.name(),
                            known.kind.name(),
                            known.name
                        ),
                    ));
                }
            }
        }
        let proj4 = epsg
            .and_then(|c| u16::try_from(c).ok())
            .and_then(crs_definitions::from_code)
            .map(|d| d.proj4.trim().to_string());
        Ok(Crs { epsg, wkt: t.to_string(), proj4, name: wkt_name(t), kind })
    }

    /// The WGS 84 / UTM zone CRS for a position (degrees).
    pub fn utm_for(lat_deg: f64, lon_deg: f64) -> Result<Crs, CrsError> {
        Self::from_epsg(utm_epsg(lat_deg, lon_deg).ok_or_else(|| {
            CrsError::invalid(&format!("latitude {lat_deg}, longitude {lon_deg}"), "outside UTM's range (80 S to 84 N)")
        })?)
    }

    /// What `transforms.json` stores: `EPSG:n` when the code is known, else the WKT.
    pub fn key(&self) -> String {
        match self.epsg {
            Some(c) => format!("EPSG:{c}"),
            None => self.wkt.clone(),
        }
    }

    /// `EPSG:32650 (WGS 84 / UTM zone 50N)` or the name alone.
    pub fn describe(&self) -> String {
        match self.epsg {
            Some(c) => format!("EPSG:{c} ({})", self.name),
            None => format!("{} (WKT, no EPSG code)", self.name),
        }
    }
}

/// EPSG code of the WGS 84 / UTM zone of a position: zone `floor((lon + 180) / 6) + 1`, 326zz north of the equator,
/// 327zz south (the plain zone formula as ODM and pyproj's `utm_crs` use, without the Norway/Svalbard exceptions).
pub fn utm_epsg(lat_deg: f64, lon_deg: f64) -> Option<u32> {
    if !(lat_deg.is_finite() && lon_deg.is_finite() && (-80.0..=84.0).contains(&lat_deg)) {
        return None;
    }
    let lon = (lon_deg + 180.0).rem_euclid(360.0);
    let zone = ((lon / 6.0).floor() as u32).min(59) + 1;
    Some(if lat_deg >= 0.0 { 32600 + zone } else { 32700 + zone })
}

/// ODM's `coords.txt` CRS line, `WGS84 UTM 32N`.
fn odm_utm(upper: &str) -> Option<u32> {
    let mut w = upper.split_whitespace();
    let (Some("WGS84"), Some("UTM"), Some(z), None) = (w.next(), w.next(), w.next(), w.next()) else {
        return None;
    };
    let (num, hemi) = z.split_at(z.len().checked_sub(1)?);
    let zone: u32 = num.parse().ok().filter(|z| (1..=60).contains(z))?;
    match hemi {
        "N" => Some(32600 + zone),
        "S" => Some(32700 + zone),
        _ => None,
    }
}

/// The EPSG code of a PROJ string for WGS84 UTM, as OpenDroneMap's `gcp_list.txt` headers and `proj.txt` carry
/// it (`+proj=utm +zone=32 +datum=WGS84 +units=m +no_defs`, `+south` for the southern hemisphere). Other datums
/// and projections are refused by name: give them as EPSG codes or WKT.
fn proj_utm(upper: &str) -> Result<u32, String> {
    let (mut utm, mut zone, mut south) = (false, None, false);
    for term in upper.split_whitespace() {
        let (k, v) = term.split_once('=').map_or((term, None), |(k, v)| (k, Some(v)));
        match (k, v) {
            ("+PROJ", Some("UTM")) => utm = true,
            ("+PROJ", Some(p)) => return Err(format!("projection {p:?}: only UTM is read from PROJ strings")),
            ("+ZONE", Some(z)) => {
                zone = Some(
                    z.parse::<u32>()
                        .ok()
                        .filter(|z| (1..=60).contains(z))
                        .ok_or(format!("zone {z:?}: UTM zones are 1..=60"))?,
                )
            }
            ("+SOUTH", None) => south = true,
            ("+DATUM" | "+ELLPS", Some("WGS84")) => {}
            ("+DATUM" | "+ELLPS", Some(d)) => return Err(format!("datum {d:?}: only WGS84 is read from PROJ strings")),
            ("+UNITS", Some("M")) | ("+NO_DEFS" | "+TYPE=CRS", None) => {}
            ("+UNITS", Some(u)) => return Err(format!("units {u:?}: metres only")),
            ("+TOWGS84", Some(t)) if t.split(',').all(|c| c.parse::<f64>().is_ok_and(|c| c == 0.0)) => {}
            _ => return Err(format!("term {term:?} is not read (give the CRS as an EPSG code)")),
        }
    }
    match (utm, zone) {
        (true, Some(z)) => Ok(if south { 32700 } else { 32600 } + z),
        (true, None) => Err("+proj=utm without +zone".into()),
        _ => Err("no +proj=utm".into()),
    }
}

/// The first quoted string of a WKT (the CRS's name).
/// What a WKT CRS's coordinates are, from its tree: a CRS needs a name and its parts (a projected CRS its base
/// geographic CRS and its projection); a compound CRS is what its horizontal part is; a vertical CRS alone, or a
/// compound without a horizontal part, has no horizontal coordinates.
fn wkt_kind(node: &wkt::Node) -> Result<CrsKind, String> {
    let k = node.keyword.to_ascii_uppercase();
    let named = matches!(node.items.first(), Some(wkt::Item::Text(n)) if !n.trim().is_empty());
    if !named {
        return Err(format!("{k}[...] has no name (its first item must be a quoted name)"));
    }
    let has = |keys: &[&str]| node.children().any(|c| keys.iter().any(|k| c.keyword.eq_ignore_ascii_case(k)));
    match k.as_str() {
        "PROJCS" | "PROJCRS" | "PROJECTEDCRS" => {
            if !has(&["GEOGCS", "BASEGEOGCRS", "BASEGEODCRS"]) {
                return Err(format!("{k}[...] has no base geographic CRS (GEOGCS or BASEGEOGCRS)"));
            }
            if !has(&["PROJECTION", "CONVERSION"]) {
                return Err(format!("{k}[...] has no projection (PROJECTION or CONVERSION)"));
            }
            Ok(CrsKind::Projected)
        }
        "GEOGCS" | "GEOGCRS" | "GEOGRAPHICCRS" => Ok(CrsKind::Geographic),
        "GEOCCS" => Ok(CrsKind::Geocentric),
        "GEODCRS" | "GEODETICCRS" => Ok(
            if node.children().any(|c| {
                c.keyword.eq_ignore_ascii_case("CS")
                    && matches!(c.items.first(), Some(wkt::Item::Word(w)) if w.eq_ignore_ascii_case("cartesian"))
            }) {
                CrsKind::Geocentric
            } else {
                CrsKind::Geographic
            },
        ),
        "COMPD_CS" | "COMPOUNDCRS" => {
            for c in node.children() {
                let ck = c.keyword.to_ascii_uppercase();
                if !matches!(ck.as_str(), "VERT_CS" | "VERTCRS" | "VERTICALCRS" | "AUTHORITY" | "ID" | "USAGE")
                    && wkt_kind(c).is_ok()
                {
                    return wkt_kind(c);
                }
            }
            Err(format!("{k}[...] has no horizontal CRS (PROJCS, GEOGCS, ...)"))
        }
        "BOUNDCRS" => match node.children().find(|c| c.keyword.eq_ignore_ascii_case("SOURCECRS")) {
            Some(src) => src.children().next().map_or_else(|| Err("BOUNDCRS[SOURCECRS[]] is empty".into()), wkt_kind),
            None => Err("BOUNDCRS[...] has no SOURCECRS".into()),
        },
        "VERT_CS" | "VERTCRS" | "VERTICALCRS" => {
            Err(format!("{k}[...] is a vertical CRS alone: it has no horizontal coordinates"))
        }
        _ => Err(format!("{k}[...] is not a CRS root msnerf reads")),
    }
}

/// Just enough of OGC WKT (1 and 2) to see its structure: `KEYWORD[item, ...]`, each item a quoted text, a bare
/// word or number, or a nested node. Brackets may be `[]` or `()`.
mod wkt {
    pub enum Item {
        Text(String),
        Word(String),
        Node(Node),
    }

    pub struct Node {
        pub keyword: String,
        pub items: Vec<Item>,
    }

    impl Node {
        pub fn children(&self) -> impl Iterator<Item = &Node> {
            self.items.iter().filter_map(|i| match i {
                Item::Node(n) => Some(n),
                _ => None,
            })
        }
    }

    pub fn parse(text: &str) -> Result<Node, String> {
        let chars: Vec<char> = text.chars().collect();
        let mut pos = 0;
        let node = node(&chars, &mut pos)?;
        skip_ws(&chars, &mut pos);
        // ESRI writes a CRS with heights as two top-level elements, `PROJCS[...],VERTCS[...]`: the vertical part
        // adds nothing horizontal and is read past.
        if chars.get(pos) == Some(&',') {
            let mut at = pos + 1;
            let vertical = self::node(&chars, &mut at)?;
            if vertical.keyword.eq_ignore_ascii_case("VERTCS") || vertical.keyword.eq_ignore_ascii_case("VERT_CS") {
                pos = at;
                skip_ws(&chars, &mut pos);
            }
        }
        if pos != chars.len() {
            return Err(format!("unexpected text after the WKT's closing bracket, at character {pos}"));
        }
        Ok(node)
    }

    fn skip_ws(c: &[char], pos: &mut usize) {
        while *pos < c.len() && c[*pos].is_whitespace() {
            *pos += 1;
        }
    }

    fn word(c: &[char], pos: &mut usize) -> String {
        let start = *pos;
        while *pos < c.len() && !matches!(c[*pos], '[' | ']' | '(' | ')' | ',' | '"') && !c[*pos].is_whitespace() {
            *pos += 1;
        }
        c[start..*pos].iter().collect()
    }

    fn node(c: &[char], pos: &mut usize) -> Result<Node, String> {
        skip_ws(c, pos);
        let keyword = word(c, pos);
        if keyword.is_empty() {
            return Err(format!("expected a WKT keyword at character {pos}"));
        }
        skip_ws(c, pos);
        let close = match c.get(*pos) {
            Some('[') => ']',
            Some('(') => ')',
            _ => return Err(format!("expected `[` after {keyword} at character {pos}")),
        };
        *pos += 1;
        let mut items = Vec::new();
        loop {
            skip_ws(c, pos);
            match c.get(*pos) {
                Some(&ch) if ch == close && items.is_empty() => {
                    *pos += 1;
                    return Ok(Node { keyword, items });
                }
                Some('"') => {
                    *pos += 1;
                    let mut t = String::new();
                    loop {
                        match c.get(*pos) {
                            // WKT escapes a quote inside text by doubling it.
                            Some('"') if c.get(*pos + 1) == Some(&'"') => {
                                t.push('"');
                                *pos += 2;
                            }
                            Some('"') => {
                                *pos += 1;
                                break;
                            }
                            Some(&ch) => {
                                t.push(ch);
                                *pos += 1;
                            }
                            None => return Err("unterminated quoted text".into()),
                        }
                    }
                    items.push(Item::Text(t));
                }
                Some(_) => {
                    let save = *pos;
                    let w = word(c, pos);
                    skip_ws(c, pos);
                    if matches!(c.get(*pos), Some('[') | Some('(')) {
                        *pos = save;
                        items.push(Item::Node(node(c, pos)?));
                    } else if w.is_empty() {
                        return Err(format!("unexpected `{}` at character {pos}", c[*pos]));
                    } else {
                        items.push(Item::Word(w));
                    }
                }
                None => return Err(format!("{keyword}[...] is not closed")),
            }
            skip_ws(c, pos);
            match c.get(*pos) {
                Some(',') => *pos += 1,
                Some(&ch) if ch == close => {
                    *pos += 1;
                    return Ok(Node { keyword, items });
                }
                Some(&ch) => return Err(format!("expected `,` or `{close}` at character {pos}, found `{ch}`")),
                None => return Err(format!("{keyword}[...] is not closed")),
            }
        }
    }
}

fn wkt_name(wkt: &str) -> String {
    wkt.split('"').nth(1).unwrap_or("unnamed").to_string()
}

/// The EPSG code of the WKT's top-level `AUTHORITY["EPSG","n"]` (WKT1) or `ID["EPSG",n]` (WKT2).
fn top_level_epsg(wkt: &str) -> Option<u32> {
    let bytes = wkt.as_bytes();
    let mut depth = 0;
    let mut found = None;
    for (i, &c) in bytes.iter().enumerate() {
        match c {
            b'[' | b'(' => {
                depth += 1;
                if depth == 2 {
                    let head = wkt[..i].rsplit([',', '[', '(']).next().unwrap_or("").trim().to_ascii_uppercase();
                    if head == "AUTHORITY" || head == "ID" {
                        let body = &wkt[i + 1..];
                        let end = body.find([']', ')']).unwrap_or(body.len());
                        let parts: Vec<&str> = body[..end].split(',').map(|s| s.trim().trim_matches('"')).collect();
                        if parts.len() >= 2 && parts[0].eq_ignore_ascii_case("EPSG") {
                            found = parts[1].parse().ok();
                        }
                    }
                }
            }
            b']' | b')' => depth -= 1,
            _ => {}
        }
    }
    found
}
