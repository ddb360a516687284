#!/usr/bin/env bash
# TEST FIXTURE ONLY. Shoal's own keystore generator is `shoal keys`; this script
# exists so that the two foreign secure peers (tests/interop/fastdds/fastdds_peer,
# tests/interop/build/cyclone_c_peer) can be tested against the OMG DDS Security 1.1
# standard independently of Shoal's code. It writes a throwaway keystore with
# nothing but the openssl CLI; never use its keys for anything but a test.
#
# Usage: tests/interop/secure/make_test_keystore.sh OUTDIR [ENCLAVE...]
#   ENCLAVE is "station" or a vehicle id (default: station auv-1 auv-2).
#
# Layout (SROS2 file names, one directory per enclave):
#   OUTDIR/private/{identity_ca,permissions_ca}.key.pem     CA keys (EC P-256)
#   OUTDIR/public/{identity_ca,permissions_ca}.cert.pem     CA certificates
#   OUTDIR/governance.xml, OUTDIR/<enclave>.permissions.xml the signed documents' sources
#   OUTDIR/enclaves/<enclave>/identity_ca.cert.pem cert.pem key.pem
#                             permissions_ca.cert.pem governance.p7s permissions.p7s
#
# Governance (every domain): allow_unauthenticated_participants false,
# enable_join_access_control true, discovery/liveliness protection ENCRYPT,
# rtps protection NONE; every topic: read/write access control on, metadata and
# data protection ENCRYPT.
# Permissions (<default>DENY</default>):
#   vehicle ID  publishes shoal/state_vector, shoal/vehicle_announcement,
#               shoal/task_status, shoal/event in partition shoal.vehicle.ID only;
#               subscribes shoal/task_assignment in the default partition
#   station     publishes shoal/task_assignment in the default partition;
#               subscribes every shoal/* topic in partitions shoal.vehicle.*
set -euo pipefail

OUT="${1:?usage: $0 OUTDIR [ENCLAVE...]}"
shift
ENCLAVES=("$@")
((${#ENCLAVES[@]})) || ENCLAVES=(station auv-1 auv-2)
DOMAINS='<domains><id_range><min>0</min><max>230</max></id_range></domains>'
NOT_BEFORE=2020-01-01T00:00:00
NOT_AFTER=2036-01-01T00:00:00

mkdir -p "$OUT/private" "$OUT/public" "$OUT/enclaves"
cd "$OUT"

ca() {  # ca <name>
    [[ -s "private/$1.key.pem" ]] && return
    openssl ecparam -name prime256v1 -genkey -noout -out "private/$1.key.pem"
    openssl req -x509 -new -sha256 -days 3650 -key "private/$1.key.pem" \
        -subj "/CN=Shoal interop test $1" -out "public/$1.cert.pem"
}
ca identity_ca
ca permissions_ca

sign() {  # sign <xml> <p7s>
    openssl smime -sign -text -in "$1" -out "$2" \
        -signer public/permissions_ca.cert.pem -inkey private/permissions_ca.key.pem
}

cat > governance.xml <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      $DOMAINS
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>NONE</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>ENCRYPT</metadata_protection_kind>
          <data_protection_kind>ENCRYPT</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
XML
sign governance.xml governance.p7s

topics() { local t; for t in "$@"; do printf '<topic>%s</topic>' "$t"; done; }

for e in "${ENCLAVES[@]}"; do
    [[ "$e" =~ ^[A-Za-z0-9_.-]{1,32}$ ]] || { echo "bad enclave name '$e'" >&2; exit 2; }
    d="enclaves/$e"
    mkdir -p "$d"
    if [[ ! -s "$d/key.pem" ]]; then
        openssl ecparam -name prime256v1 -genkey -noout -out "$d/key.pem"
        openssl req -new -sha256 -key "$d/key.pem" -subj "/CN=$e" -out "$d/cert.csr"
        openssl x509 -req -sha256 -days 3650 -in "$d/cert.csr" -CA public/identity_ca.cert.pem \
            -CAkey private/identity_ca.key.pem -CAcreateserial -out "$d/cert.pem" \
            -extfile <(printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\n') \
            2>/dev/null
        rm -f "$d/cert.csr"
    fi
    if [[ "$e" == station ]]; then
        rule="<publish><topics>$(topics shoal/task_assignment)</topics></publish>
        <subscribe><topics>$(topics 'shoal/*')</topics>
          <partitions><partition>shoal.vehicle.*</partition></partitions></subscribe>"
    else
        rule="<publish><topics>$(topics shoal/state_vector shoal/vehicle_announcement shoal/task_status shoal/event)</topics>
          <partitions><partition>shoal.vehicle.$e</partition></partitions></publish>
        <subscribe><topics>$(topics shoal/task_assignment)</topics></subscribe>"
    fi
    cat > "$e.permissions.xml" <<XML
<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance"
     xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="$e">
      <subject_name>CN=$e</subject_name>
      <validity><not_before>$NOT_BEFORE</not_before><not_after>$NOT_AFTER</not_after></validity>
      <allow_rule>
        $DOMAINS
        $rule
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
XML
    sign "$e.permissions.xml" "$d/permissions.p7s"
    cp governance.p7s "$d/governance.p7s"
    cp public/identity_ca.cert.pem "$d/identity_ca.cert.pem"
    cp public/permissions_ca.cert.pem "$d/permissions_ca.cert.pem"
done
echo "test keystore (fixture, not 'shoal keys'): $OUT/enclaves/{$(IFS=,; echo "${ENCLAVES[*]}")}"
