//! The X.509 and S/MIME work OMG DDS Security needs, through OpenSSL: the same library the
//! Cyclone DDS and Fast DDS plugins verify these files with, so what Shoal issues is what
//! they accept.
//!
//! Keys are EC P-256 (`prime256v1`), the curve the standard's PKI-DH plugin names beside
//! RSA-2048; signatures are ECDSA with SHA-256.

use openssl::asn1::{Asn1Integer, Asn1Object, Asn1OctetString, Asn1Time};
use openssl::bn::{BigNum, MsbOption};
use openssl::ec::{EcGroup, EcKey};
use openssl::error::ErrorStack;
use openssl::hash::MessageDigest;
use openssl::nid::Nid;
use openssl::pkcs7::{Pkcs7, Pkcs7Flags};
use openssl::pkey::{PKey, PKeyRef, Private};
use openssl::stack::Stack;
use openssl::x509::extension::{BasicConstraints, KeyUsage, SubjectKeyIdentifier};
use openssl::x509::store::X509StoreBuilder;
use openssl::x509::{
    X509, X509Builder, X509Crl, X509CrlBuilder, X509Extension, X509Name, X509NameRef, X509Ref,
    X509RevokedBuilder,
};

/// Seconds in a day.
const DAY_S: i64 = 86_400;
/// Certificates start ten minutes in the past, so a peer whose clock runs a little behind
/// still accepts a certificate issued a moment ago.
const BACKDATE_S: i64 = 600;

/// A new EC P-256 private key.
pub(crate) fn new_key() -> Result<PKey<Private>, ErrorStack> {
    let group = EcGroup::from_curve_name(Nid::X9_62_PRIME256V1)?;
    PKey::from_ec_key(EcKey::generate(&group)?)
}

/// `CN=<common_name>,O=<organisation>` as an X.509 name (in this DER order). The permissions documents write
/// the same name as text (see [`subject_text`]); the plugins compare the two.
pub(crate) fn subject(common_name: &str, organisation: &str) -> Result<X509Name, ErrorStack> {
    let mut name = X509Name::builder()?;
    name.append_entry_by_nid(Nid::COMMONNAME, common_name)?;
    name.append_entry_by_nid(Nid::ORGANIZATIONNAME, organisation)?;
    Ok(name.build())
}

/// The text form of [`subject`] for a permissions document's `<subject_name>`: RFC 2253,
/// which writes a name's attributes in the reverse of their DER order
/// (`O=<organisation>,CN=<common_name>`), as OpenSSL prints it with `XN_FLAG_RFC2253`.
/// Fast DDS 2.9 compares the two strings attribute by attribute in order, so the other
/// order makes it refuse its own permissions; Cyclone DDS compares them in any order.
pub(crate) fn subject_text(common_name: &str, organisation: &str) -> String {
    format!("O={organisation},CN={common_name}")
}

/// The text form of a certificate's subject, as [`subject_text`] writes it (`O=...` if
/// present, then `CN=...`).
pub(crate) fn name_text(name: &X509NameRef) -> Option<String> {
    let cn = common_name_of(name)?;
    let org = name
        .entries_by_nid(Nid::ORGANIZATIONNAME)
        .next()
        .and_then(|e| e.data().to_string().ok());
    Some(match org {
        Some(o) => subject_text(&cn, &o),
        None => format!("CN={cn}"),
    })
}

/// SHA-256 of the DER encoding of `name`: the plugins take the first 47 bits of a
/// participant's adjusted GUID from it (DDS Security 1.1 §9.3.3), which decides who
/// starts the authentication handshake.
#[cfg(test)]
pub(crate) fn subject_hash(name: &X509NameRef) -> Result<[u8; 32], ErrorStack> {
    Ok(openssl::sha::sha256(&name.to_der()?))
}

/// A DER tag, length and value (values up to 64 KiB, far more than a subject needs).
fn der_tlv(tag: u8, body: &[u8]) -> Vec<u8> {
    let mut out = vec![tag];
    let n = body.len();
    if n < 0x80 {
        out.push(n as u8);
    } else if n <= 0xFF {
        out.extend([0x81, n as u8]);
    } else {
        out.extend([0x82, (n >> 8) as u8, n as u8]);
    }
    out.extend_from_slice(body);
    out
}

/// The DER [`subject`] produces (OpenSSL encodes both attributes as UTF8String), without
/// OpenSSL: [`lowest_organisation`] builds tens of thousands of them.
fn subject_der(common_name: &str, organisation: &str) -> Vec<u8> {
    let attribute = |oid_last: u8, value: &str| {
        let mut atv = der_tlv(0x06, &[0x55, 0x04, oid_last]);
        atv.extend(der_tlv(0x0C, value.as_bytes()));
        der_tlv(0x31, &der_tlv(0x30, &atv))
    };
    let mut rdns = attribute(0x03, common_name);
    rdns.extend(attribute(0x0A, organisation));
    der_tlv(0x30, &rdns)
}

/// The organisation `"<base> <nonce>"` (nonce: lower-case hex, the first that fits) that
/// makes SHA-256 of the DER subject `CN=<common_name>,O=<organisation>` start with two
/// zero bytes. A participant with such a subject has an adjusted GUID below almost any
/// other's, and the builtin PKI-DH plugins let the participant with the lower adjusted
/// GUID send the handshake request (Cyclone DDS `validate_remote_identity`, Fast DDS
/// `PKIDH::validate_remote_identity`). Deterministic: the same name always gives the
/// same nonce (about 65 000 hashes on average).
pub(crate) fn lowest_organisation(common_name: &str, base: &str) -> String {
    use sha2::Digest as _;
    (0u64..)
        .map(|n| format!("{base} {n:04x}"))
        .find(|org| {
            let h = sha2::Sha256::digest(subject_der(common_name, org));
            h[0] == 0 && h[1] == 0
        })
        .unwrap_or_else(|| base.to_string())
}
fn random_serial() -> Result<Asn1Integer, ErrorStack> {
    let mut bn = BigNum::new()?;
    // 159 bits, positive: RFC 5280 allows up to 20 octets and asks for unpredictability.
    bn.rand(159, MsbOption::MAYBE_ZERO, false)?;
    bn.to_asn1_integer()
}

fn validity(builder: &mut X509Builder, now_s: i64, days: u32) -> Result<(), ErrorStack> {
    let not_before = Asn1Time::from_unix(now_s - BACKDATE_S)?;
    let not_after = Asn1Time::from_unix(now_s + i64::from(days) * DAY_S)?;
    builder.set_not_before(&not_before)?;
    builder.set_not_after(&not_after)
}

/// A self-signed CA certificate for `key`.
pub(crate) fn ca_certificate(
    key: &PKeyRef<Private>,
    common_name: &str,
    now_s: i64,
    days: u32,
) -> Result<X509, ErrorStack> {
    let name = subject(common_name, super::ORGANISATION)?;
    let mut b = X509Builder::new()?;
    b.set_version(2)?;
    let serial = random_serial()?;
    b.set_serial_number(&serial)?;
    b.set_subject_name(&name)?;
    b.set_issuer_name(&name)?;
    b.set_pubkey(key)?;
    validity(&mut b, now_s, days)?;
    b.append_extension(BasicConstraints::new().critical().ca().build()?)?;
    b.append_extension(
        KeyUsage::new()
            .critical()
            .key_cert_sign()
            .crl_sign()
            // The permissions CA signs documents itself (S/MIME), so PKCS#7 verifiers
            // check it for a signing purpose.
            .digital_signature()
            .build()?,
    )?;
    let ski = SubjectKeyIdentifier::new().build(&b.x509v3_context(None, None))?;
    b.append_extension(ski)?;
    b.sign(key, MessageDigest::sha256())?;
    Ok(b.build())
}

/// An identity certificate for `subject_key`, issued by `ca`, with the subject
/// `CN=<common_name>,O=<organisation>`.
pub(crate) fn leaf_certificate(
    ca: &X509Ref,
    ca_key: &PKeyRef<Private>,
    subject_key: &PKeyRef<Private>,
    (common_name, organisation): (&str, &str),
    now_s: i64,
    days: u32,
) -> Result<X509, ErrorStack> {
    let mut b = X509Builder::new()?;
    b.set_version(2)?;
    let serial = random_serial()?;
    b.set_serial_number(&serial)?;
    let name = subject(common_name, organisation)?;
    b.set_subject_name(&name)?;
    b.set_issuer_name(ca.subject_name())?;
    b.set_pubkey(subject_key)?;
    validity(&mut b, now_s, days)?;
    b.append_extension(BasicConstraints::new().critical().build()?)?;
    b.append_extension(
        KeyUsage::new()
            .critical()
            .digital_signature()
            .key_agreement()
            .build()?,
    )?;
    b.sign(ca_key, MessageDigest::sha256())?;
    Ok(b.build())
}

/// Signs `document` as S/MIME (`multipart/signed`, the text/plain header included in the
/// signed part), as `openssl smime -sign -text` does and as the plugins expect.
pub(crate) fn smime_sign(
    signer: &X509Ref,
    key: &PKeyRef<Private>,
    document: &[u8],
) -> Result<Vec<u8>, ErrorStack> {
    let flags = Pkcs7Flags::DETACHED | Pkcs7Flags::TEXT;
    let no_extra = Stack::new()?;
    let p7 = Pkcs7::sign(signer, key, &no_extra, document, flags)?;
    p7.to_smime(document, flags)
}

/// Checks an S/MIME signed document against `ca` and returns the document.
pub(crate) fn smime_verify(ca: &X509Ref, smime: &[u8]) -> Result<Vec<u8>, ErrorStack> {
    let (p7, content) = Pkcs7::from_smime(smime)?;
    let mut store = X509StoreBuilder::new()?;
    store.add_cert(ca.to_owned())?;
    let store = store.build();
    let no_extra = Stack::new()?;
    let mut out = Vec::new();
    p7.verify(
        &no_extra,
        &store,
        content.as_deref(),
        Some(&mut out),
        Pkcs7Flags::TEXT,
    )?;
    Ok(out)
}

/// A CRL from `ca` listing `revoked` serial numbers (hex), valid for `days`.
pub(crate) fn crl(
    ca: &X509Ref,
    ca_key: &PKeyRef<Private>,
    revoked: &[(String, i64)],
    now_s: i64,
    days: u32,
) -> Result<X509Crl, ErrorStack> {
    let mut b = X509CrlBuilder::new()?;
    b.set_issuer_name(ca.subject_name())?;
    let last = Asn1Time::from_unix(now_s - BACKDATE_S)?;
    let next = Asn1Time::from_unix(now_s + i64::from(days) * DAY_S)?;
    b.set_last_update(&last)?;
    b.set_next_update(&next)?;
    // RFC 5280 §5.2.1 and §5.2.3: which CA key signed the list, and a number that grows
    // with each list (the issue time serves: lists are never issued twice a second).
    let ski = ca
        .subject_key_id()
        .map(|k| k.as_slice().to_vec())
        .unwrap_or_default();
    let mut aki = vec![0x30, (ski.len() + 2) as u8, 0x80, ski.len() as u8];
    aki.extend_from_slice(&ski);
    b.append_extension(extension(Nid::AUTHORITY_KEY_IDENTIFIER, &aki)?)?;
    b.append_extension(extension(
        Nid::CRL_NUMBER,
        &der_integer(now_s.max(0) as u64),
    )?)?;
    for (serial_hex, at_s) in revoked {
        let mut r = X509RevokedBuilder::new()?;
        let serial = BigNum::from_hex_str(serial_hex)?.to_asn1_integer()?;
        let at = Asn1Time::from_unix(*at_s)?;
        r.set_serial_number(&serial)?;
        r.set_revocation_date(&at)?;
        b.add_revoked(r.build())?;
    }
    b.sign(ca_key, MessageDigest::sha256())?;
    b.build()
}

fn extension(nid: Nid, der: &[u8]) -> Result<X509Extension, ErrorStack> {
    let oid = Asn1Object::from_str(nid.short_name()?)?;
    let value = Asn1OctetString::new_from_bytes(der)?;
    X509Extension::new_from_der(&oid, false, &value)
}

/// A non-negative DER INTEGER.
fn der_integer(n: u64) -> Vec<u8> {
    let bytes = n.to_be_bytes();
    let first = bytes.iter().position(|b| *b != 0).unwrap_or(7);
    let mut body = bytes[first..].to_vec();
    if body[0] & 0x80 != 0 {
        body.insert(0, 0);
    }
    let mut out = vec![0x02, body.len() as u8];
    out.extend(body);
    out
}

/// The certificate's serial number in upper-case hex.
pub(crate) fn serial_hex(cert: &X509Ref) -> Result<String, ErrorStack> {
    Ok(cert.serial_number().to_bn()?.to_hex_str()?.to_string())
}

/// True when `name` carries `common_name` as its CN.
pub(crate) fn common_name_of(name: &X509NameRef) -> Option<String> {
    name.entries_by_nid(Nid::COMMONNAME)
        .next()
        .and_then(|e| e.data().to_string().ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    const NOW: i64 = 1_790_000_000;

    #[test]
    fn a_leaf_verifies_against_its_ca_and_not_another() {
        let ca_key = new_key().unwrap();
        let ca = ca_certificate(&ca_key, "ca", NOW, 10).unwrap();
        let other_key = new_key().unwrap();
        let leaf_key = new_key().unwrap();
        let leaf =
            leaf_certificate(&ca, &ca_key, &leaf_key, ("/shoal/station", "Shoal"), NOW, 5).unwrap();
        assert!(leaf.verify(&ca.public_key().unwrap()).unwrap());
        assert!(!leaf.verify(&other_key).unwrap());
        assert_eq!(
            common_name_of(leaf.subject_name()).as_deref(),
            Some("/shoal/station")
        );
    }

    #[test]
    fn smime_round_trip_and_tamper() {
        let ca_key = new_key().unwrap();
        let ca = ca_certificate(&ca_key, "permissions ca", NOW, 3650).unwrap();
        let doc = b"<dds><permissions/></dds>\n";
        let signed = smime_sign(&ca, &ca_key, doc).unwrap();
        let text = String::from_utf8(signed.clone()).unwrap();
        assert!(text.contains("multipart/signed"), "{text}");
        // S/MIME canonicalises line ends to CRLF.
        let back = smime_verify(&ca, &signed).unwrap();
        assert_eq!(
            String::from_utf8(back)
                .unwrap()
                .replace("\r\n", "\n")
                .as_bytes(),
            doc
        );

        let tampered = text.replace("<permissions/>", "<permissions />");
        assert!(smime_verify(&ca, tampered.as_bytes()).is_err());

        let other_key = new_key().unwrap();
        let other = ca_certificate(&other_key, "other", NOW, 3650).unwrap();
        assert!(smime_verify(&other, &signed).is_err());
    }

    #[test]
    fn subject_der_is_what_openssl_encodes() {
        for (cn, o) in [
            ("/shoal/station", "Shoal 1a2b"),
            (&"x".repeat(60)[..], &"y".repeat(60)[..]),
        ] {
            assert_eq!(
                subject_der(cn, o),
                subject(cn, o).unwrap().to_der().unwrap(),
                "{cn}"
            );
        }
        let org = lowest_organisation("/shoal/station", "Shoal");
        let name = subject("/shoal/station", &org).unwrap();
        assert_eq!(subject_hash(&name).unwrap()[..2], [0, 0], "{org}");
    }

    #[test]
    fn crl_lists_serials() {
        let ca_key = new_key().unwrap();
        let ca = ca_certificate(&ca_key, "ca", NOW, 10).unwrap();
        let leaf_key = new_key().unwrap();
        let leaf = leaf_certificate(&ca, &ca_key, &leaf_key, ("x", "Shoal"), NOW, 5).unwrap();
        let serial = serial_hex(&leaf).unwrap();
        let crl = crl(&ca, &ca_key, &[(serial, NOW)], NOW, 7).unwrap();
        assert!(crl.verify(&ca.public_key().unwrap()).unwrap());
        assert!(matches!(
            crl.get_by_cert(&leaf),
            openssl::x509::CrlStatus::Revoked(_)
        ));
    }
}
