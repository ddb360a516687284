use super::*;

const HEAD: &str = "[scenario]\nname = \"t\"\n\n[[vehicles]]\nid = \"auv-1\"\nkind = \"auv\"\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n";

fn err(text: &str) -> ScenarioError {
    match parse(text) {
        Ok(s) => panic!("parsed: {s:?}"),
        Err(e) => e,
    }
}

/// One line, naming the key and the line: what every error must say.
fn assert_names(e: &ScenarioError, line: usize, key: &str) {
    let text = e.to_string();
    assert_eq!(e.line(), line, "{text}");
    assert!(text.starts_with(&format!("line {line}: ")), "{text}");
    assert!(text.contains(key), "{key:?} not in {text}");
    assert!(!text.contains('\n'), "{text}");
}

#[test]
fn every_shipped_scenario_parses_and_every_file_in_scenarios_is_shipped() {
    for (name, text) in SHIPPED {
        let s = parse(text).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(&s.name, name);
        assert!(!s.missions.is_empty(), "{name}");
    }
    assert!(shipped(DEFAULT).is_some());
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenarios");
    for f in std::fs::read_dir(&dir).unwrap() {
        let path = f.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
            let on_disk = std::fs::read_to_string(&path).unwrap();
            assert_eq!(
                shipped(&stem),
                Some(on_disk.as_str()),
                "{stem} not in SHIPPED"
            );
        }
    }
}

/// `shoal up`'s default scenario drives the default fleet, and moves it early.
#[test]
fn the_default_scenario_moves_every_vehicle_within_ten_seconds() {
    let s = parse(shipped(DEFAULT).unwrap()).unwrap();
    let ids: Vec<_> = s.vehicles.iter().map(|v| v.id.as_str()).collect();
    assert_eq!(ids, ["auv-1", "auv-2", "usv-1", "rov-1", "auv-ac1"]);
    // The acoustic AUV is the one shoal up's acoustic demo ran before scenarios had one.
    let ac: Vec<_> = s.acoustic_vehicles().map(|v| v.id.as_str()).collect();
    assert_eq!(ac, ["auv-ac1"]);
    for v in &s.vehicles {
        assert!(
            s.missions
                .iter()
                .any(|m| m.at_s <= 10.0 && m.vehicles().contains(&v.id.as_str())),
            "{} has nothing to do in the first 10 s",
            v.id
        );
    }
    let usv = s.missions.iter().find(|m| m.id == "usv-transit").unwrap();
    assert!(matches!(
        usv.tasks[0].task,
        Task::GotoWaypoint { depth_m: Some(d), .. } if d == 0.0
    ));
}

#[test]
fn defaults_fill_what_is_left_out() {
    let s = parse(HEAD).unwrap();
    assert_eq!(s.duration_s, 3600.0);
    assert_eq!(s.time_scale, 1.0);
    assert_eq!(s.vehicles[0].battery_pct, 100.0);
    assert_eq!(s.vehicles[0].rate_hz, 1.0);
    let s = parse(&format!(
        "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"hold\"\n"
    ))
    .unwrap();
    assert_eq!(s.missions[0].id, "mission-1");
    assert_eq!(s.missions[0].tasks[0].task, Task::Hold { duration_s: 0.0 });
}

/// A hold until the next task followed by another task of the same vehicle would never
/// let that task go: refused at load, as the station would refuse the mission; as the
/// vehicle's last task it is fine.
#[test]
fn a_hold_until_the_next_task_must_be_its_vehicles_last() {
    let mission = |second: &str| {
        format!(
            "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"hold\"\n\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"{second}\"\n"
        )
    };
    let e = err(&mission("return_home"));
    assert_names(&e, 15, "missions[0].tasks[0].duration_s");
    assert!(e.to_string().contains("last task"), "{e}");
    let with_end = mission("return_home").replacen(
        "kind = \"hold\"\n",
        "kind = \"hold\"\nduration_s = 60\n",
        1,
    );
    assert!(parse(&with_end).is_ok());
}

#[test]
fn an_unknown_key_is_named_with_its_line() {
    let e = err(&format!("{HEAD}colour = \"red\"\n"));
    assert!(matches!(e, ScenarioError::Format { .. }), "{e}");
    assert_names(&e, 9, "colour");
    let e = err("[scenario]\nname = \"t\"\nspeed = 3\n");
    assert_names(&e, 3, "speed");
}

#[test]
fn a_value_of_the_wrong_type_is_named_with_its_key_and_line() {
    let e = err(&HEAD.replace("latitude_deg = 63.0", "latitude_deg = \"north\""));
    assert_names(&e, 7, "vehicles[0].latitude_deg");
    let e = err(&HEAD.replace("kind = \"auv\"", "kind = \"submarine\""));
    assert_names(&e, 6, "vehicles[0].kind");
}

#[test]
fn broken_toml_and_a_missing_key_give_a_line() {
    let e = err("[scenario]\nname = \"t\n");
    assert_names(&e, 2, "file");
    let e = err(&HEAD.replace("longitude_deg = 10.0\n", ""));
    assert_names(&e, 4, "longitude_deg");
}

#[test]
fn a_mission_naming_an_unknown_vehicle_is_refused() {
    let e = err(&format!(
        "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n\n[[missions.tasks]]\nvehicle = \"auv-9\"\nkind = \"surface\"\n"
    ));
    assert!(matches!(e, ScenarioError::UnknownVehicle { .. }), "{e}");
    assert_names(&e, 15, "missions[0].tasks[0].vehicle");
    assert!(e.to_string().contains("auv-9"));
}

#[test]
fn out_of_range_values_are_refused_with_their_bounds() {
    let e = err(&HEAD.replace("latitude_deg = 63.0", "latitude_deg = 91.5"));
    assert!(matches!(e, ScenarioError::OutOfRange { .. }), "{e}");
    assert_names(&e, 7, "vehicles[0].latitude_deg");
    assert!(e.to_string().contains("[-90, 90]"), "{e}");
    let e = err(&HEAD.replace("longitude_deg = 10.0", "longitude_deg = -181"));
    assert_names(&e, 8, "vehicles[0].longitude_deg");
    let e = err(&format!("{HEAD}battery_pct = 120\n"));
    assert_names(&e, 9, "battery_pct");
    let e = err(&format!(
        "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"goto\"\nlatitude_deg = 95.0\nlongitude_deg = 10.0\ndepth_m = 2\n"
    ));
    assert_names(&e, 16, "missions[0].tasks[0].latitude_deg");
    let e = err(&format!(
        "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"survey\"\nspacing_m = 10\ndepth_m = 2\npolygon = [[63.0, 10.0], [63.1, 10.0], [63.1, 190.0]]\n"
    ));
    assert_names(&e, 18, "polygon[2] longitude");
    // A mission after the end of the scenario.
    let e = err(&format!(
        "{}\n[[missions]]\nname = \"m\"\nat_s = 100\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"surface\"\n",
        HEAD.replace("name = \"t\"", "name = \"t\"\nduration_s = 60")
    ));
    assert_names(&e, 13, "missions[0].at_s");
}

#[test]
fn duplicate_ids_name_both_lines() {
    let e = err(&format!(
        "{HEAD}\n[[vehicles]]\nid = \"auv-1\"\nkind = \"usv\"\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n"
    ));
    assert!(
        matches!(e, ScenarioError::Duplicate { first_line: 5, .. }),
        "{e}"
    );
    assert_names(&e, 11, "vehicles[1].id");
    let m = |id: &str| {
        format!(
            "\n[[missions]]\nid = \"{id}\"\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"surface\"\n"
        )
    };
    let e = err(&format!("{HEAD}{}{}", m("a"), m("a")));
    assert_names(&e, 19, "missions[1].id");
    // A given id equal to another mission's default one.
    let e = err(&format!("{HEAD}{}{}", m("x"), m("mission-1")).replacen("id = \"x\"\n", "", 1));
    assert!(matches!(e, ScenarioError::Duplicate { .. }), "{e}");
}

#[test]
fn task_keys_must_fit_the_task_kind() {
    let task = |body: &str| {
        format!(
            "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\n{body}"
        )
    };
    // A key another kind uses.
    let e = err(&task("kind = \"hold\"\nspacing_m = 3\n"));
    assert_names(&e, 16, "missions[0].tasks[0].spacing_m");
    // A key the kind needs.
    let e = err(&task("kind = \"goto\"\nlatitude_deg = 63.0\ndepth_m = 1\n"));
    assert_names(&e, 15, "longitude_deg");
    // An AUV must be told a depth or an altitude.
    let e = err(&task(
        "kind = \"goto\"\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n",
    ));
    assert_names(&e, 15, "depth_m");
    // The data model's own check: a self-intersecting (bow-tie) polygon.
    let e = err(&task(
        "kind = \"survey\"\nspacing_m = 10\ndepth_m = 2\npolygon = [[63.0, 10.0], [63.1, 10.1], [63.0, 10.1], [63.1, 10.0]]\n",
    ));
    assert!(matches!(e, ScenarioError::Invalid { .. }), "{e}");
    assert_names(&e, 15, "missions[0].tasks[0].kind");
    let e = err(&task("kind = \"dance\"\n"));
    assert_names(&e, 15, "missions[0].tasks[0].kind");
}

mod prop {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Whatever bytes come in, the answer is a scenario or one error line with a line
        /// number inside the file.
        #[test]
        fn any_text_gives_a_scenario_or_one_line(text in "\\PC{0,200}") {
            if let Err(e) = parse(&text) {
                let s = e.to_string();
                prop_assert!(!s.contains('\n'), "{}", s);
                prop_assert!(e.line() >= 1 && e.line() <= text.lines().count().max(1) + 1);
            }
        }

        /// Any in-range start position of a vehicle is accepted and kept exactly.
        #[test]
        fn in_range_positions_round_trip(lat in -90.0f64..=90.0, lon in -180.0f64..=180.0) {
            let text = HEAD
                .replace("latitude_deg = 63.0", &format!("latitude_deg = {lat:?}"))
                .replace("longitude_deg = 10.0", &format!("longitude_deg = {lon:?}"));
            let s = parse(&text).unwrap();
            prop_assert_eq!(s.vehicles[0].latitude_deg, lat);
            prop_assert_eq!(s.vehicles[0].longitude_deg, lon);
        }
    }
}

#[test]
fn faults_are_read_with_their_defaults() {
    let s = parse(&format!(
        "{HEAD}\n[[faults]]\nat_s = 10\nkind = \"vehicle_failure\"\nvehicle = \"auv-1\"\nduration_s = 30\n\
         [[faults]]\nat_s = 20\nkind = \"battery_drop\"\nvehicle = \"auv-1\"\nbattery_pct = 12\n\
         [[faults]]\nat_s = 30\nkind = \"rogue_sample\"\nvehicle = \"auv-1\"\n\
         [[faults]]\nat_s = 40\nkind = \"station_restart\"\n\
         [[faults]]\nat_s = 50\nkind = \"vehicle_failure\"\nvehicle = \"auv-1\"\n"
    ))
    .unwrap();
    let kinds: Vec<&str> = s.faults.iter().map(|f| f.fault.kind()).collect();
    assert_eq!(
        kinds,
        [
            "vehicle_failure",
            "battery_drop",
            "rogue_sample",
            "station_restart",
            "vehicle_failure"
        ]
    );
    assert_eq!(
        s.faults[0].fault,
        Fault::VehicleFailure {
            vehicle: "auv-1".into(),
            restart_after_s: Some(30.0)
        }
    );
    assert_eq!(s.faults[3].fault, Fault::StationRestart { down_s: 5.0 });
    assert_eq!(
        s.faults[4].fault,
        Fault::VehicleFailure {
            vehicle: "auv-1".into(),
            restart_after_s: None
        }
    );
    assert_eq!(s.faults[1].at_s, 20.0);
}

#[test]
fn a_bad_fault_is_named_with_its_key_and_line() {
    let e = err(&format!(
        "{HEAD}\n[[faults]]\nat_s = 10\nkind = \"rogue_sample\"\nvehicle = \"auv-9\"\n"
    ));
    assert!(matches!(e, ScenarioError::UnknownVehicle { .. }), "{e}");
    assert_names(&e, 13, "faults[0].vehicle");
    let e = err(&format!(
        "{HEAD}\n[[faults]]\nat_s = 10\nkind = \"battery_drop\"\nvehicle = \"auv-1\"\n"
    ));
    assert_names(&e, 12, "faults[0].battery_pct");
    let e = err(&format!(
        "{HEAD}\n[[faults]]\nat_s = 10\nkind = \"station_restart\"\nvehicle = \"auv-1\"\n"
    ));
    assert_names(&e, 13, "faults[0].vehicle");
    let e = err(&format!(
        "{HEAD}\n[[faults]]\nat_s = 10\nkind = \"meteor\"\n"
    ));
    assert_names(&e, 12, "faults[0].kind");
    let e = err(&format!(
        "{}\n[[faults]]\nat_s = 100\nkind = \"station_restart\"\n",
        HEAD.replace("name = \"t\"", "name = \"t\"\nduration_s = 60")
    ));
    assert_names(&e, 12, "faults[0].at_s");
}

/// HEAD (auv-1 on IP at 63.0, 10.0) and a relay 1.1 km north of it.
const NET: &str = "\n[acoustic]\nrelay_latitude_deg = 63.01\nrelay_longitude_deg = 10.0\n";

fn acoustic_vehicle(id: &str, extra: &str) -> String {
    format!(
        "\n[[vehicles]]\nid = \"{id}\"\nkind = \"auv\"\nlatitude_deg = 63.005\nlongitude_deg = 10.0\nlink = \"acoustic\"\n{extra}"
    )
}

#[test]
fn acoustic_vehicles_get_addresses_and_their_faults_are_read() {
    let text = format!(
        "{HEAD}{NET}per = 0.2\n{}{}{}\n[[faults]]\nat_s = 10\nkind = \"link_outage\"\nvehicle = \"ac-1\"\nduration_s = 60\n\
         [[faults]]\nat_s = 20\nkind = \"modem_failure\"\n\
         [[faults]]\nat_s = 30\nkind = \"modem_failure\"\nvehicle = \"ac-2\"\nduration_s = 5\n\
         [[faults]]\nat_s = 40\nkind = \"battery_drop\"\nvehicle = \"ac-2\"\nbattery_pct = 10\n",
        acoustic_vehicle("ac-1", ""),
        acoustic_vehicle("ac-2", "acoustic_address = 2\n"),
        acoustic_vehicle("ac-3", ""),
    );
    let s = parse(&text).unwrap();
    let net = s.acoustic.clone().unwrap();
    assert_eq!((net.relay_address, net.fixed_per), (1, Some(0.2)));
    let addr: Vec<_> = s.vehicles.iter().map(|v| v.acoustic_address).collect();
    // The relay has 1, ac-2 asked for 2: the others take the lowest free ones.
    assert_eq!(addr, [None, Some(3), Some(2), Some(4)]);
    assert_eq!(s.acoustic_vehicles().count(), 3);
    assert_eq!(
        s.faults[0].fault,
        Fault::LinkOutage {
            vehicle: "ac-1".into(),
            duration_s: 60.0
        }
    );
    assert_eq!(
        s.faults[1].fault,
        Fault::ModemFailure {
            vehicle: None,
            repaired_after_s: None
        }
    );
    assert_eq!(
        s.faults[2].fault,
        Fault::ModemFailure {
            vehicle: Some("ac-2".into()),
            repaired_after_s: Some(5.0)
        }
    );
    assert_eq!(s.faults[3].fault.kind(), "battery_drop");
}

#[test]
fn bad_acoustic_networks_are_one_line_naming_the_key() {
    // An acoustic vehicle with no relay.
    let e = err(&format!("{HEAD}{}", acoustic_vehicle("ac-1", "")));
    assert_names(&e, 15, "vehicles[1].link");
    assert!(e.to_string().contains("[acoustic]"), "{e}");
    // Out of range of the relay: 9.5 km.
    let e = err(&format!(
        "{HEAD}\n[acoustic]\nrelay_latitude_deg = 63.09\nrelay_longitude_deg = 10.0\n{}",
        acoustic_vehicle("ac-1", "")
    ));
    assert_names(&e, 17, "vehicles[1].latitude_deg");
    assert!(e.to_string().contains("out of acoustic range"), "{e}");
    // The relay's address taken, an address out of range, an address on an IP vehicle.
    let e = err(&format!(
        "{HEAD}{NET}{}",
        acoustic_vehicle("ac-1", "acoustic_address = 1\n")
    ));
    assert_names(&e, 20, "vehicles[1].acoustic_address");
    let e = err(&format!(
        "{HEAD}{NET}{}",
        acoustic_vehicle("ac-1", "acoustic_address = 16\n")
    ));
    assert_names(&e, 20, "vehicles[1].acoustic_address");
    let e = err(&format!("{HEAD}acoustic_address = 3\n"));
    assert_names(&e, 9, "vehicles[0].acoustic_address");
    let e = err(&format!("{HEAD}{NET}per = 1.5\n"));
    assert_names(&e, 13, "acoustic.per");
    let e = err(&format!("{HEAD}{NET}range_m = 5\n"));
    assert_names(&e, 13, "range_m");
    // Acoustic faults: on an IP vehicle, without a network, with a key missing.
    let fault = |body: &str| format!("\n[[faults]]\nat_s = 5\n{body}");
    let e = err(&format!(
        "{HEAD}{NET}{}",
        fault("kind = \"link_outage\"\nvehicle = \"auv-1\"\nduration_s = 5\n")
    ));
    assert_names(&e, 17, "faults[0].vehicle");
    let e = err(&format!("{HEAD}{}", fault("kind = \"modem_failure\"\n")));
    assert_names(&e, 12, "faults[0].kind");
    let e = err(&format!(
        "{HEAD}{NET}{}{}",
        acoustic_vehicle("ac-1", ""),
        fault("kind = \"link_outage\"\nvehicle = \"ac-1\"\n")
    ));
    assert_names(&e, 23, "faults[0].duration_s");
}

#[test]
fn a_relay_can_ride_on_an_ip_vehicle() {
    let text = format!(
        "{HEAD}\n[acoustic]\nrelay_vehicle = \"auv-1\"\n{}",
        acoustic_vehicle("ac-1", "")
    );
    let net = parse(&text).unwrap().acoustic.unwrap();
    assert_eq!(net.relay_vehicle.as_deref(), Some("auv-1"));
    assert_eq!(
        (net.relay_latitude_deg, net.relay_longitude_deg),
        (63.0, 10.0)
    );
    // Not an acoustic vehicle, not one outside the fleet, not with a position too, and
    // not no position at all.
    let e = err(&format!(
        "{HEAD}\n[acoustic]\nrelay_vehicle = \"ac-1\"\n{}",
        acoustic_vehicle("ac-1", "")
    ));
    assert_names(&e, 11, "acoustic.relay_vehicle");
    let e = err(&format!("{HEAD}\n[acoustic]\nrelay_vehicle = \"nobody\"\n"));
    assert_names(&e, 11, "acoustic.relay_vehicle");
    let e = err(&format!(
        "{HEAD}\n[acoustic]\nrelay_vehicle = \"auv-1\"\nrelay_latitude_deg = 63.0\n"
    ));
    assert_names(&e, 12, "acoustic.relay_latitude_deg");
    let e = err(&format!("{HEAD}\n[acoustic]\nper = 0.1\n"));
    assert!(e.to_string().contains("relay_latitude_deg"), "{e}");
}

#[test]
fn a_vehicle_waypoint_or_relay_on_land_is_refused_by_line_and_key() {
    // Trondheim's centre, on the shipped chart.
    let land = HEAD.replace(
        "latitude_deg = 63.0\nlongitude_deg = 10.0",
        "latitude_deg = 63.43\nlongitude_deg = 10.395",
    );
    let e = err(&land);
    assert_names(&e, 7, "vehicles[0].latitude_deg");
    assert!(
        e.to_string()
            .contains("auv-1 starts (63.43, 10.395) is on land"),
        "{e}"
    );
    let e = err(&format!(
        "{HEAD}\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-1\"\nkind = \"goto\"\nlatitude_deg = 63.43\nlongitude_deg = 10.395\ndepth_m = 5\n"
    ));
    assert_names(&e, 16, "missions[0].tasks[0].latitude_deg");
    let e = err(&format!(
        "{HEAD}\n[acoustic]\nrelay_latitude_deg = 63.43\nrelay_longitude_deg = 10.395\n"
    ));
    assert_names(&e, 11, "acoustic.relay_latitude_deg");
    // At sea in the fjord, and anywhere off the chart, is fine.
    let sea = HEAD.replace(
        "latitude_deg = 63.0\nlongitude_deg = 10.0",
        "latitude_deg = 63.465\nlongitude_deg = 10.37",
    );
    assert!(parse(&sea).is_ok());
    assert!(parse(HEAD).is_ok());
}

#[test]
fn the_environment_section_shapes_the_ocean_and_defaults_to_the_simulators() {
    assert_eq!(parse(HEAD).unwrap().environment, OceanField::default());
    let s = parse(&format!(
        "{HEAD}\n[environment]\nsurface_temperature_c = 7.5\nthermocline_m = 15\ncurrent_mps = 0.1\n\n\
         [[environment.plumes]]\nlatitude_deg = 63.01\nlongitude_deg = 10.02\nradius_m = 400\n\
         salinity_psu = -6\n\n[[environment.plumes]]\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n\
         radius_m = 100\ndepth_m = 30\nthickness_m = 5\ntemperature_c = 3\n"
    ))
    .unwrap();
    let e = &s.environment;
    assert_eq!(e.surface_temperature_c, Some(7.5));
    assert_eq!((e.thermocline_m, e.current_mps), (15.0, 0.1));
    assert_eq!(
        e.eddy_temperature_c,
        OceanField::default().eddy_temperature_c
    );
    assert_eq!(e.plumes.len(), 2);
    assert_eq!(
        (
            e.plumes[0].salinity_psu,
            e.plumes[0].depth_m,
            e.plumes[0].thickness_m
        ),
        (-6.0, 0.0, 10.0)
    );
    assert_eq!(
        (e.plumes[1].depth_m, e.plumes[1].temperature_c),
        (30.0, 3.0)
    );
}

#[test]
fn a_bad_environment_is_one_line_naming_the_key() {
    let base = HEAD.lines().count() + 2;
    let e = err(&format!(
        "{HEAD}\n[environment]\nsurface_temperature_c = 60\n"
    ));
    assert_names(&e, base + 1, "environment.surface_temperature_c");
    let e = err(&format!("{HEAD}\n[environment]\nsalinity = 30\n"));
    assert_names(&e, base + 1, "salinity");
    let plume = "[[environment.plumes]]\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n";
    let e = err(&format!("{HEAD}\n{plume}radius_m = 0\ntemperature_c = 2\n"));
    assert_names(&e, base + 3, "environment.plumes[0].radius_m");
    let e = err(&format!("{HEAD}\n{plume}radius_m = 100\n"));
    assert_names(&e, base + 3, "environment.plumes[0].temperature_c");
    let e = err(&format!(
        "{HEAD}\n{plume}radius_m = 100\nsalinity_psu = -50\n"
    ));
    assert_names(&e, base + 4, "environment.plumes[0].salinity_psu");
    let many = plume.to_owned() + "radius_m = 10\ntemperature_c = 1\n";
    let e = err(&format!("{HEAD}\n{}", many.repeat(MAX_PLUMES + 1)));
    assert!(e.to_string().contains("at most 32 plumes"), "{e}");
}

#[test]
fn the_channels_physics_can_be_set_and_are_checked() {
    let s = parse(&format!(
        "{HEAD}{NET}\n[acoustic.channel]\nsource_level_db = 170\ncentre_khz = 12\nbandwidth_khz = 6\n\
         wind_mps = 12\nmodulation = \"non_coherent_fsk\"\n{}",
        acoustic_vehicle("ac-1", "")
    ))
    .unwrap();
    let c = s.acoustic.unwrap().channel;
    assert_eq!(
        (c.source_level_db, c.centre_khz, c.bandwidth_khz),
        (170.0, 12.0, 6.0)
    );
    assert_eq!(
        (c.wind_mps, c.modulation),
        (12.0, Modulation::NonCoherentFsk)
    );
    assert_eq!(c.spreading_k, ChannelModel::default().spreading_k);
    // Without the section: the emulator's defaults.
    let plain = parse(&format!("{HEAD}{NET}{}", acoustic_vehicle("ac-1", ""))).unwrap();
    assert_eq!(plain.acoustic.unwrap().channel, ChannelModel::default());

    let base = HEAD.lines().count() + NET.lines().count();
    let e = err(&format!(
        "{HEAD}{NET}\n[acoustic.channel]\nspreading_k = 3\n"
    ));
    assert_names(&e, base + 3, "acoustic.channel.spreading_k");
    let e = err(&format!(
        "{HEAD}{NET}\n[acoustic.channel]\ncentre_khz = 5\nbandwidth_khz = 20\n"
    ));
    assert_names(&e, base + 4, "acoustic.channel.bandwidth_khz");
    let e = err(&format!(
        "{HEAD}{NET}per = 0.1\n\n[acoustic.channel]\nwind_mps = 3\n"
    ));
    assert_names(&e, base + 1, "acoustic.per");
    let e = err(&format!(
        "{HEAD}{NET}\n[acoustic.channel]\nmodulation = \"ofdm\"\n"
    ));
    assert_names(&e, base + 3, "modulation");
}
