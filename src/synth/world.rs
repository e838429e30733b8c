//! Worlds by name: the option sets of the simulator that datasets and models were made in.
//!
//! `mlod synth --world NAME` starts from a world and lets each individual option override it; its
//! default, [`World::SHIPPED`], is the world the shipped models were trained in (recorded as
//! `world` in `assets/models/manifest.json`).

use super::{CarSizes, SensorPreset, SynthConfig};

/// Share of the beams that pass a vehicle's side glass in a see-through world.
pub const GLASS_PASS: f64 = 0.8;

/// A named world of the simulator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum World {
    /// The first world: Lyft's Pandar40 on the roof, one car body of uniform size, reflectance
    /// intensity, opaque glass, no walls at the curb ([`SynthConfig::default`]).
    V2,
    /// Sensor randomisation: every roof LiDAR preset with ±0.2 m mount height, mixed car sizes,
    /// Lyft's constant intensity of 100.
    V4,
    /// V4 with see-through side glass (80 % of beams pass; a beam through the glass that meets
    /// nothing else returns nothing) and walls or hedges behind half the curb stretches: the
    /// world of the shipped models.
    Walled,
}

impl World {
    pub const ALL: [World; 3] = [World::V2, World::V4, World::Walled];

    /// The world the shipped models were trained in: the default of `mlod synth`.
    pub const SHIPPED: World = World::Walled;

    pub fn name(self) -> &'static str {
        match self {
            World::V2 => "v2",
            World::V4 => "v4",
            World::Walled => "walled",
        }
    }

    /// A world by its name, or an error listing the names.
    pub fn parse(s: &str) -> Result<World, String> {
        World::ALL.into_iter().find(|w| w.name() == s).ok_or_else(|| {
            let names: Vec<&str> = World::ALL.iter().map(|w| w.name()).collect();
            format!("{s}: not a world (one of {})", names.join(", "))
        })
    }

    /// The simulator's configuration of this world (seed, scenes and samples at their defaults).
    pub fn config(self) -> SynthConfig {
        let mut c = SynthConfig::default();
        if self == World::V2 {
            return c;
        }
        c.roof.presets = SensorPreset::ALL.to_vec();
        c.roof.height_jitter_m = 0.2;
        c.car_sizes = CarSizes::Mixed;
        c.lidar.constant_intensity = Some(100.0);
        if self == World::Walled {
            c.lidar.glass_pass = GLASS_PASS;
            c.lidar.glass_ground = false;
            c.curb_walls = 0.5;
        }
        c
    }
}

impl std::fmt::Display for World {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worlds_parse_by_name_and_differ() {
        for w in World::ALL {
            assert_eq!(World::parse(w.name()), Ok(w));
            assert!(w.config().validate().is_ok());
        }
        assert!(World::parse("v3").unwrap_err().contains("v2, v4, walled"));
        assert_eq!(World::V2.config(), SynthConfig::default());
        let (v4, walled) = (World::V4.config(), World::Walled.config());
        assert_ne!(v4, SynthConfig::default());
        assert_eq!(
            (
                walled.lidar.glass_pass,
                walled.lidar.glass_ground,
                walled.curb_walls
            ),
            (GLASS_PASS, false, 0.5)
        );
        assert_eq!(v4.roof, walled.roof);
        assert_eq!(World::SHIPPED, World::Walled);
    }
}
