//! One set of category names for every format: Lyft Level 5's (`car`, `pedestrian`, …), which the
//! detectors, the evaluation and the simulator use. nuScenes and KITTI names are mapped onto them
//! here (and Argoverse 2's), in one table (docs/data.md prints it); a name the table does not know keeps its own name,
//! so its boxes are shown and listed but never scored against ours, and the dataset lists it as
//! unmapped.

/// Our categories (Lyft Level 5's nine).
pub const OURS: [&str; 9] = [
    "car",
    "pedestrian",
    "animal",
    "other_vehicle",
    "bus",
    "motorcycle",
    "truck",
    "emergency_vehicle",
    "bicycle",
];

/// (source name, our name). nuScenes' detection-benchmark classes map as its devkit groups them;
/// KITTI's as its classes describe them.
pub const MAPPING: [(&str, &str); 24] = [
    // nuScenes
    ("vehicle.car", "car"),
    ("vehicle.truck", "truck"),
    ("vehicle.bus.bendy", "bus"),
    ("vehicle.bus.rigid", "bus"),
    ("vehicle.trailer", "other_vehicle"),
    ("vehicle.construction", "other_vehicle"),
    ("vehicle.emergency.ambulance", "emergency_vehicle"),
    ("vehicle.emergency.police", "emergency_vehicle"),
    ("vehicle.motorcycle", "motorcycle"),
    ("vehicle.bicycle", "bicycle"),
    ("human.pedestrian.adult", "pedestrian"),
    ("human.pedestrian.child", "pedestrian"),
    ("human.pedestrian.construction_worker", "pedestrian"),
    ("human.pedestrian.police_officer", "pedestrian"),
    ("human.pedestrian.wheelchair", "pedestrian"),
    ("human.pedestrian.stroller", "pedestrian"),
    ("human.pedestrian.personal_mobility", "pedestrian"),
    ("animal", "animal"),
    // KITTI
    ("Car", "car"),
    ("Van", "other_vehicle"),
    ("Truck", "truck"),
    ("Pedestrian", "pedestrian"),
    ("Person_sitting", "pedestrian"),
    ("Cyclist", "bicycle"),
];

/// KITTI's `Tram` has no counterpart among ours that fits better than other_vehicle; kept apart
/// from [`MAPPING`] only to keep that table's length readable.
const EXTRA: [(&str, &str); 1] = [("Tram", "other_vehicle")];

/// Argoverse 2's classes (its sensor dataset's 30). Riders (BICYCLIST, MOTORCYCLIST,
/// WHEELED_RIDER) are people on a vehicle that is labelled on its own; they, the static objects
/// (BOLLARD, SIGN, CONSTRUCTION_CONE, …), STROLLER, WHEELCHAIR and WHEELED_DEVICE have no
/// counterpart among ours and stay unmapped.
pub const AV2: [(&str, &str); 14] = [
    ("REGULAR_VEHICLE", "car"),
    ("LARGE_VEHICLE", "other_vehicle"),
    ("BUS", "bus"),
    ("SCHOOL_BUS", "bus"),
    ("ARTICULATED_BUS", "bus"),
    ("BOX_TRUCK", "truck"),
    ("TRUCK", "truck"),
    ("TRUCK_CAB", "truck"),
    ("VEHICULAR_TRAILER", "other_vehicle"),
    ("RAILED_VEHICLE", "other_vehicle"),
    ("MOTORCYCLE", "motorcycle"),
    ("BICYCLE", "bicycle"),
    ("PEDESTRIAN", "pedestrian"),
    ("DOG", "animal"),
];

/// Our name for a source category; `None` when the name is not ours and not in the table
/// (nuScenes `movable_object.*`, `static_object.*`, KITTI `Misc`, …).
pub fn canonical(name: &str) -> Option<&'static str> {
    if let Some(ours) = OURS.iter().find(|o| **o == name) {
        return Some(ours);
    }
    MAPPING
        .iter()
        .chain(EXTRA.iter())
        .chain(AV2.iter())
        .find(|(from, _)| *from == name)
        .map(|(_, to)| *to)
}

/// The name a box gets: ours when mapped, else its own.
pub fn display_name(name: &str) -> String {
    canonical(name).map_or_else(|| name.to_owned(), str::to_owned)
}

/// Every row of the mapping, for the docs and `mlod inspect`.
pub fn table() -> impl Iterator<Item = (&'static str, &'static str)> {
    MAPPING.iter().chain(EXTRA.iter()).chain(AV2.iter()).copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_onto_ours() {
        assert_eq!(canonical("car"), Some("car"));
        assert_eq!(canonical("vehicle.car"), Some("car"));
        assert_eq!(canonical("human.pedestrian.child"), Some("pedestrian"));
        assert_eq!(canonical("vehicle.bicycle"), Some("bicycle"));
        assert_eq!(canonical("Car"), Some("car"));
        assert_eq!(canonical("Cyclist"), Some("bicycle"));
        assert_eq!(canonical("Tram"), Some("other_vehicle"));
        assert_eq!(canonical("movable_object.barrier"), None);
        assert_eq!(canonical("Misc"), None);
        assert_eq!(canonical("REGULAR_VEHICLE"), Some("car"));
        assert_eq!(canonical("BOLLARD"), None);
        assert_eq!(display_name("Misc"), "Misc");
        // Every target is one of ours.
        for (_, to) in table() {
            assert!(OURS.contains(&to), "{to}");
        }
    }
}
