//! Points that a modelling program computed and stored beside the markers, told by their
//! names: Plug-in Gait's segment axes.
//!
//! Plug-in Gait writes each segment's frame as four points named by a three-letter segment
//! code and a letter: `O` the origin, `A` anterior, `L` lateral, `P` proximal (`PELO`,
//! `PELA`, `PELL`, `PELP` for the pelvis), and the body's centre of mass as
//! `CentreOfMass` and `CentreOfMassFloor`. No C3D group names them; they follow the model's
//! segments rather than the skin, often rigid with each other to the file's rounding, and
//! would be read as markers. Only a full quartet of a known code counts, so a marker that
//! happens to be called `PELO` stays.

/// Plug-in Gait's segment codes: head, thorax, pelvis, and per side clavicle, humerus,
/// radius, hand, femur, tibia, foot and toe.
const SEGMENT_CODES: [&str; 19] = [
    "HED", "TRX", "PEL", "LCL", "RCL", "LHU", "RHU", "LRA", "RRA", "LHN", "RHN", "LFE", "RFE",
    "LTI", "RTI", "LFO", "RFO", "LTO", "RTO",
];

/// The letters of a segment's four axis points.
const AXIS_LETTERS: [char; 4] = ['O', 'A', 'L', 'P'];

/// Plug-in Gait's centre-of-mass outputs.
const CENTRE_OF_MASS: [&str; 2] = ["CentreOfMass", "CentreOfMassFloor"];

/// Indices (ascending) of the labels that are Plug-in Gait segment axes or centre-of-mass
/// outputs. Labels are compared after trimming and without a subject prefix (`Bob:PELO`).
pub(crate) fn segment_axes(labels: &[String]) -> Vec<usize> {
    let bare: Vec<&str> = labels
        .iter()
        .map(|l| {
            let l = l.trim();
            l.rsplit_once(':').map_or(l, |(_, name)| name)
        })
        .collect();
    let has = |name: &str| bare.contains(&name);
    let full_codes: Vec<&str> = SEGMENT_CODES
        .into_iter()
        .filter(|code| AXIS_LETTERS.iter().all(|c| has(&format!("{code}{c}"))))
        .collect();
    bare.iter()
        .enumerate()
        .filter(|(_, name)| {
            CENTRE_OF_MASS.contains(name)
                || (name.len() == 4
                    && name.is_char_boundary(3)
                    && full_codes.contains(&&name[..3])
                    && name[3..].chars().all(|c| AXIS_LETTERS.contains(&c)))
        })
        .map(|(i, _)| i)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(names: &[&str]) -> Vec<String> {
        names.iter().map(|s| (*s).to_string()).collect()
    }

    #[test]
    fn full_quartets_of_segment_codes_and_the_centre_of_mass_are_told() {
        let l = labels(&[
            "LASI",
            "PELO",
            "PELA",
            "PELL",
            "PELP",
            "LTIB",
            "LFEO",
            "LFEA",
            "LFEL",
            "CentreOfMass",
            "S:RTOO",
            "S:RTOA",
            "S:RTOL",
            "S:RTOP",
        ]);
        // LFE lacks its P point: its three stay, as does LTIB (a marker on the tibia).
        assert_eq!(segment_axes(&l), [1, 2, 3, 4, 9, 10, 11, 12, 13]);
        assert!(segment_axes(&labels(&["PELO", "LASI", "RASI"])).is_empty());
        assert!(segment_axes(&labels(&["ÅÅO"])).is_empty());
    }
}
