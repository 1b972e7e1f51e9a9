//! Band identity from XMP packets (TIFF tag 700): `Camera:BandName`, `Camera:CentralWavelength`,
//! `Camera:WavelengthFWHM` (the Pix4D camera namespace that MicaSense and most rigs write).
//!
//! Parsed with `roxmltree` (small, no unsafe, read-only DOM) rather than by string search, because vendors
//! write the same property either as a child element (MicaSense) or as an attribute of `rdf:Description`
//! (DJI style), possibly wrapped in `rdf:Seq`/`rdf:Alt`. We match on the local name, in either form.

/// Band facts found in one file's XMP. Every field is optional.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct XmpBand {
    pub name: Option<String>,
    pub center_nm: Option<f64>,
    pub fwhm_nm: Option<f64>,
}

impl XmpBand {
    pub fn is_empty(&self) -> bool {
        self.name.is_none() && self.center_nm.is_none() && self.fwhm_nm.is_none()
    }
}

/// Parses an XMP packet (raw tag bytes; trailing NULs and padding allowed). Returns `None` when the bytes
/// are not XML; an `XmpBand` with empty fields when the tags are absent.
pub fn parse_xmp_band(bytes: &[u8]) -> Option<XmpBand> {
    let text = std::str::from_utf8(bytes).ok()?;
    let text = text.trim_end_matches(['\0', ' ', '\n', '\r', '\t']);
    // An xpacket wrapper is fine for roxmltree (processing instructions), but some writers put text before it.
    let start = text.find('<')?;
    let doc = roxmltree::Document::parse(&text[start..]).ok()?;
    let mut out = XmpBand::default();
    for node in doc.descendants() {
        if node.is_element() {
            for attr in node.attributes() {
                set_field(&mut out, attr.name(), attr.value());
            }
            let local = node.tag_name().name();
            if matches!(local, "BandName" | "CentralWavelength" | "WavelengthFWHM") {
                if let Some(v) = element_value(node) {
                    set_field(&mut out, local, &v);
                }
            }
        }
    }
    Some(out)
}

/// Text of an element, or of its first `rdf:li` when the value is a sequence.
fn element_value(node: roxmltree::Node) -> Option<String> {
    if let Some(li) = node.descendants().find(|n| n.is_element() && n.tag_name().name() == "li") {
        return li.text().map(|t| t.trim().to_string());
    }
    node.text().map(|t| t.trim().to_string()).filter(|t| !t.is_empty())
}

fn set_field(out: &mut XmpBand, local: &str, value: &str) {
    let value = value.trim();
    match local {
        "BandName" if out.name.is_none() && !value.is_empty() => out.name = Some(value.to_string()),
        "CentralWavelength" if out.center_nm.is_none() => {
            out.center_nm = first_number(value);
        }
        "WavelengthFWHM" if out.fwhm_nm.is_none() => out.fwhm_nm = first_number(value),
        _ => {}
    }
}

/// First number in a value like "475", "475.0" or "475,560" (attribute lists).
fn first_number(v: &str) -> Option<f64> {
    v.split([',', ' ']).find(|s| !s.is_empty()).and_then(|s| s.parse::<f64>().ok()).filter(|x| x.is_finite())
}
