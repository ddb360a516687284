use super::*;

const NOW: i64 = 1_790_000_000;

fn store() -> (tempfile::TempDir, DdsKeystore) {
    let tmp = tempfile::tempdir().unwrap();
    let ks = DdsKeystore::create(&tmp.path().join("dds"), KeystoreOptions::default(), NOW).unwrap();
    (tmp, ks)
}

#[test]
fn issued_enclaves_check_and_carry_the_sros2_files() {
    let (_tmp, ks) = store();
    let station = ks.issue(&Grant::Station, NOW).unwrap();
    let auv = ks.issue(&Grant::Vehicle("auv-1".into()), NOW).unwrap();
    for n in [
        names::CERT,
        names::KEY,
        names::IDENTITY_CA,
        names::PERMISSIONS_CA,
        names::GOVERNANCE,
        names::PERMISSIONS,
        names::PERMISSIONS_XML,
    ] {
        assert!(auv.file(n).exists(), "{n}");
    }
    assert!(auv.dir().ends_with("enclaves/shoal/vehicle/auv-1"));
    assert_eq!(station.check(NOW).unwrap().common_name, "/shoal/station");
    assert_eq!(auv.check(NOW).unwrap().common_name, "/shoal/vehicle/auv-1");
    assert_eq!(
        ks.enclaves().unwrap(),
        vec![Grant::Station, Grant::Vehicle("auv-1".into())]
    );
    assert!(matches!(
        ks.issue(&Grant::Station, NOW),
        Err(DdsKeyError::EnclaveExists(_))
    ));
    assert!(matches!(
        DdsKeystore::create(ks.dir(), KeystoreOptions::default(), NOW),
        Err(DdsKeyError::Exists(_))
    ));
}

#[test]
fn keys_are_private() {
    use std::os::unix::fs::PermissionsExt;
    let (_tmp, ks) = store();
    let e = ks.issue(&Grant::Station, NOW).unwrap();
    let mode = |p: &Path| fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&e.file(names::KEY)), 0o600);
    assert_eq!(
        mode(&ks.dir().join("private").join(names::IDENTITY_CA_KEY)),
        0o600
    );
}

#[test]
fn a_bad_file_is_named_with_its_problem() {
    let (_tmp, ks) = store();
    let e = ks.issue(&Grant::Vehicle("auv-2".into()), NOW).unwrap();

    // Expired.
    let err = e.check(NOW + 400 * 86_400).unwrap_err();
    assert!(err.path.ends_with(names::CERT), "{err}");
    assert!(matches!(err.problem, FileProblem::Expired(_)), "{err}");

    // Garbage certificate.
    let cert = fs::read(e.file(names::CERT)).unwrap();
    fs::write(e.file(names::CERT), b"not a certificate").unwrap();
    let err = e.check(NOW).unwrap_err();
    assert!(
        err.path.ends_with(names::CERT) && err.to_string().contains("certificate"),
        "{err}"
    );
    fs::write(e.file(names::CERT), &cert).unwrap();

    // Tampered permissions: one byte of the signed XML changed.
    let perms = fs::read_to_string(e.file(names::PERMISSIONS)).unwrap();
    fs::write(
        e.file(names::PERMISSIONS),
        perms.replace("shoal.vehicle.auv-2", "shoal.vehicle.auv-3"),
    )
    .unwrap();
    let err = e.check(NOW).unwrap_err();
    assert!(err.path.ends_with(names::PERMISSIONS), "{err}");
    assert!(
        err.to_string().contains("signed by the permissions CA"),
        "{err}"
    );
    fs::write(e.file(names::PERMISSIONS), perms).unwrap();

    // Another vehicle's key.
    let other = ks.issue(&Grant::Vehicle("auv-3".into()), NOW).unwrap();
    let key = fs::read(e.file(names::KEY)).unwrap();
    fs::copy(other.file(names::KEY), e.file(names::KEY)).unwrap();
    let err = e.check(NOW).unwrap_err();
    assert!(matches!(err.problem, FileProblem::KeyMismatch(_)), "{err}");
    fs::write(e.file(names::KEY), key).unwrap();

    // Another vehicle's permissions: validly signed, but not for this subject.
    fs::copy(other.file(names::PERMISSIONS), e.file(names::PERMISSIONS)).unwrap();
    let err = e.check(NOW).unwrap_err();
    assert!(
        err.to_string()
            .contains("grants nothing to O=Shoal,CN=/shoal/vehicle/auv-2"),
        "{err}"
    );
}

#[test]
fn a_certificate_from_another_ca_is_refused() {
    let (_tmp, ks) = store();
    let (_tmp2, other) = store();
    let e = ks.issue(&Grant::Vehicle("auv-1".into()), NOW).unwrap();
    let foreign = other.issue(&Grant::Vehicle("auv-1".into()), NOW).unwrap();
    fs::copy(foreign.file(names::CERT), e.file(names::CERT)).unwrap();
    let err = e.check(NOW).unwrap_err();
    assert!(
        err.to_string().contains("not issued by the identity CA"),
        "{err}"
    );
}

#[test]
fn revoked_certificates_are_listed_and_refused_and_rotation_issues_anew() {
    let (_tmp, ks) = store();
    let old = ks.issue(&Grant::Vehicle("auv-1".into()), NOW).unwrap();
    let old_serial = old.check(NOW).unwrap().serial;
    let kept_cert = fs::read(old.file(names::CERT)).unwrap();
    let new = ks
        .rotate(&Grant::Vehicle("auv-1".into()), NOW + 10)
        .unwrap();
    let new_serial = new.check(NOW + 10).unwrap().serial;
    assert_ne!(old_serial, new_serial);
    let revoked = ks.revoked().unwrap();
    assert_eq!(revoked.len(), 1);
    assert_eq!(revoked[0].serial, old_serial);
    // The old certificate put back in place is refused by the list.
    fs::write(new.file(names::CERT), kept_cert).unwrap();
    let err = new.check(NOW + 10).unwrap_err();
    assert!(err.to_string().contains("revoked"), "{err}");
    assert!(ks.dir().join("retired").exists());
}

#[test]
fn bad_vehicle_ids_are_refused() {
    let (_tmp, ks) = store();
    assert!(matches!(
        ks.issue(&Grant::Vehicle("../x".into()), NOW),
        Err(DdsKeyError::BadName(_))
    ));
}

#[test]
fn the_station_subject_hash_sorts_lowest_so_the_station_initiates_handshakes() {
    let (_tmp, ks) = store();
    let station = ks.issue(&Grant::Station, NOW).unwrap();
    let auv = ks.issue(&Grant::Vehicle("auv-1".into()), NOW).unwrap();
    let cert = read_cert(&station.file(names::CERT)).unwrap();
    let hash = pki::subject_hash(cert.subject_name()).unwrap();
    assert_eq!(hash[..2], [0, 0], "{hash:02x?}");
    let org = Grant::Station.organisation();
    assert!(org.starts_with("Shoal "), "{org}");
    // The permissions name exactly the certificate's subject, and the enclave checks.
    let perms = fs::read_to_string(station.file(names::PERMISSIONS_XML)).unwrap();
    assert!(
        perms.contains(&format!(
            "<subject_name>O={org},CN=/shoal/station</subject_name>"
        )),
        "{perms}"
    );
    assert_eq!(station.check(NOW).unwrap().common_name, "/shoal/station");
    // Vehicles keep their plain subject.
    let cert = read_cert(&auv.file(names::CERT)).unwrap();
    assert_eq!(
        pki::name_text(cert.subject_name()).unwrap(),
        "O=Shoal,CN=/shoal/vehicle/auv-1"
    );
    assert!(auv.check(NOW).is_ok());
}
