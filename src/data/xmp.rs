//! Band identity from XMP packets (TIFF tag 700): `Camera:BandName`, `Camera:CentralWavelength`,
//! `Camera:WavelengthFWHM` (the Pix4D camera namespace that MicaSense and most rigs write).
//!
//! [`XmpProps`] keeps every property of a packet (by namespace URI and local name, values of `rdf:Seq`/`rdf:Alt`
//! lists in order) for the raw-rig importer (`crate::rig`), which needs the `MicaSense:`, `DLS:` and `drone-dji:`
//! namespaces as well.
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

/// Every property of an XMP packet: (namespace URI, local name) -> values (one for a plain value or attribute,
/// several for an `rdf:Seq`/`rdf:Bag`/`rdf:Alt` list), in document order.
#[derive(Debug, Clone, Default)]
pub struct XmpProps {
    props: Vec<(String, String, Vec<String>)>,
}

impl XmpProps {
    /// Parses a packet (trailing NULs and padding allowed); `None` when the bytes are not XML.
    pub fn parse(bytes: &[u8]) -> Option<XmpProps> {
        let text = std::str::from_utf8(bytes).ok()?;
        let text = text.trim_end_matches(['\0', ' ', '\n', '\r', '\t']);
        let start = text.find('<')?;
        let doc = roxmltree::Document::parse(&text[start..]).ok()?;
        let mut props = Vec::new();
        for node in doc.descendants().filter(|n| n.is_element() && n.tag_name().name() == "Description") {
            for attr in node.attributes() {
                let ns = attr.namespace().unwrap_or("");
                if ns.contains("www.w3.org/1999/02/22-rdf-syntax-ns") || ns.is_empty() {
                    continue;
                }
                props.push((ns.to_string(), attr.name().to_string(), vec![attr.value().trim().to_string()]));
            }
            for child in node.children().filter(|n| n.is_element()) {
                let ns = child.tag_name().namespace().unwrap_or("").to_string();
                let items: Vec<String> = child
                    .descendants()
                    .filter(|n| n.is_element() && n.tag_name().name() == "li")
                    .filter_map(|li| li.text().map(|t| t.trim().to_string()))
                    .collect();
                let values = if items.is_empty() {
                    child.text().map(|t| vec![t.trim().to_string()]).unwrap_or_default()
                } else {
                    items
                };
                props.push((ns, child.tag_name().name().to_string(), values));
            }
        }
        Some(XmpProps { props })
    }

    /// Values of the first property named `local` whose namespace URI contains `ns` (`""`: any namespace).
    pub fn get(&self, ns: &str, local: &str) -> Option<&[String]> {
        self.props.iter().find(|(n, l, _)| l == local && n.contains(ns)).map(|(_, _, v)| v.as_slice())
    }

    /// The first value of a property as text.
    pub fn text(&self, ns: &str, local: &str) -> Option<&str> {
        self.get(ns, local).and_then(|v| v.first()).map(String::as_str).filter(|s| !s.is_empty())
    }

    /// Every number of a property: list items, or the comma/space separated numbers of one value.
    pub fn numbers(&self, ns: &str, local: &str) -> Option<Vec<f64>> {
        let values = self.get(ns, local)?;
        let mut out = Vec::new();
        for v in values {
            for part in v.split([',', ' ', ';']).filter(|s| !s.is_empty()) {
                out.push(part.parse::<f64>().ok().filter(|x| x.is_finite())?);
            }
        }
        (!out.is_empty()).then_some(out)
    }

    /// The first number of a property.
    pub fn number(&self, ns: &str, local: &str) -> Option<f64> {
        self.numbers(ns, local).and_then(|v| v.first().copied())
    }

    /// Whether any property lives in a namespace whose URI contains `ns`.
    pub fn has_namespace(&self, ns: &str) -> bool {
        self.props.iter().any(|(n, _, _)| n.contains(ns))
    }
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
