// Shoal interop peer on eProsima Fast DDS 2.9 (Debian 12: libfastrtps-dev,
// libfastcdr-dev 1.0.x).
//
// fastddsgen is not packaged in Debian, so the TopicDataType implementations
// for the Shoal types are written here by hand with fastcdr: plain XCDR1 CDR
// (encapsulation CDR_LE 0x0001 written, CDR_LE/CDR_BE read), member order and
// bounds exactly as idl/shoal.idl, module-qualified type names
// ("shoal::StateVector"). getKey follows RTPS 2.x 9.6.3.8: big-endian plain CDR
// of the key members, MD5 of it when the maximum key size exceeds 16 bytes
// (always, for Shoal's bounded-string keys).
//
// Same command-line interface as tests/interop/peers/cyclone_peer.py:
//   publish-state  --vehicle-id ID --count N --rate HZ [--linger S] [--settle S]
//   subscribe-task --vehicle-id ID --expect N --timeout S
//   publish-task   --vehicle-id ID --task-id T [--linger S] [--wait-match S]
//   subscribe-state --expect N --timeout S [--vehicle-id ID] [--expect-announcements K]
//   --domain D (anywhere; default 0)
// Options for the secure interop tests (tests/interop/README.md, "Secure peers");
// without them the peer behaves exactly as before:
//   --security DIR     OMG DDS Security 1.1 builtin plugins (PKI-DH, Access-Permissions,
//                      AES-GCM-GMAC) from an SROS2-style enclave directory: identity_ca.cert.pem,
//                      cert.pem, key.pem, permissions_ca.cert.pem, governance.p7s, permissions.p7s
//   --partition P      PARTITION QoS of the Publisher of every writer (default: none)
//   --read-partition P PARTITION QoS of the Subscriber of every reader (default: none;
//                      wildcards allowed, e.g. 'shoal.vehicle.*')
//   --attack           for publish-state / publish-task: an attempt the remote side should
//                      refuse. Never gives up: a refused writer, no matched reader or a failed
//                      write is reported on stdout ("attack ..." lines) and the peer goes on;
//                      exit 0 once the attempt is made (1 only on a usage/setup error)
//   --match-timeout S  how long publish-state waits for a StateVector reader (default 20)
// Extra, no DDS traffic:
//   encode-demo <StateVector|VehicleAnnouncement|TaskAssignment>
//       prints a fixed sample as a JSON line, then its XCDR1 little-endian
//       bytes as hex WITHOUT the 4-byte encapsulation header
//   key-hash <StateVector|VehicleAnnouncement|TaskAssignment> <key>
//       prints the 16-byte instance handle getKey() computes, as hex
// Machine-readable lines go to stdout, logs to stderr.

#include <fastcdr/Cdr.h>
#include <fastcdr/FastBuffer.h>
#include <fastcdr/exceptions/Exception.h>
#include <fastdds/dds/core/policy/QosPolicies.hpp>
#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/log/Log.hpp>
#include <fastdds/dds/log/StdoutErrConsumer.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/PublisherQos.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/SubscriberQos.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TopicDataType.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>
#include <fastdds/rtps/transport/UDPv4TransportDescriptor.h>
#include <fastrtps/utils/md5.h>

#include <atomic>
#include <charconv>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

using namespace eprosima::fastdds::dds;
using eprosima::fastdds::rtps::UDPv4TransportDescriptor;
using eprosima::fastrtps::rtps::InstanceHandle_t;
using eprosima::fastrtps::rtps::SerializedPayload_t;
namespace fcdr = eprosima::fastcdr;

static const char* PEER = "fastdds";

// ------------------------------------------------------------------ helpers

static std::atomic<bool> g_stop{false};
static std::atomic<int> g_stop_code{130};  // 128 + signal number

static void on_signal(int sig)
{
    g_stop_code = 128 + sig;
    g_stop = true;
}

static int64_t now_ms()
{
    return std::chrono::duration_cast<std::chrono::milliseconds>(
               std::chrono::system_clock::now().time_since_epoch())
        .count();
}

static void log(const std::string& msg)
{
    std::cerr << "[" << PEER << "] " << msg << std::endl;
}

static void emit(const std::string& line)
{
    std::cout << line << std::endl;  // endl flushes: one line per sample
}

// Sleep in small steps; false if a stop signal arrived.
static bool sleep_unless_stopped(double seconds)
{
    auto end = std::chrono::steady_clock::now() +
               std::chrono::microseconds(static_cast<int64_t>(seconds * 1e6));
    while (std::chrono::steady_clock::now() < end) {
        if (g_stop) return false;
        auto left = end - std::chrono::steady_clock::now();
        std::this_thread::sleep_for(std::min<std::chrono::steady_clock::duration>(
            left, std::chrono::milliseconds(50)));
    }
    return !g_stop;
}

static std::string json_str(const std::string& s)
{
    std::string o = "\"";
    for (unsigned char c : s) {
        switch (c) {
            case '"': o += "\\\""; break;
            case '\\': o += "\\\\"; break;
            case '\n': o += "\\n"; break;
            case '\r': o += "\\r"; break;
            case '\t': o += "\\t"; break;
            default:
                if (c < 0x20) {
                    char b[8];
                    std::snprintf(b, sizeof b, "\\u%04x", c);
                    o += b;
                } else {
                    o += static_cast<char>(c);
                }
        }
    }
    return o + "\"";
}

// Shortest round-trip representation, like Python's repr(float).
static std::string json_num(double d)
{
    char b[64];
    auto r = std::to_chars(b, b + sizeof b, d);
    std::string s(b, r.ptr);
    if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
    return s;
}

static std::string hex(const unsigned char* p, size_t n)
{
    static const char* d = "0123456789abcdef";
    std::string s;
    for (size_t i = 0; i < n; ++i) {
        s += d[p[i] >> 4];
        s += d[p[i] & 15];
    }
    return s;
}

// --------------------------------------------------------------- CDR access

// Writes through fastcdr (alignment handled by fastcdr, relative to the end of
// the encapsulation header in DDS_CDR mode: 8 for int64/double = XCDR1).
struct CdrOut {
    fcdr::Cdr& c;
    void str(const std::string& s, size_t bound)
    {
        if (s.size() > bound) throw std::length_error("string exceeds its bound");
        c.serialize(s);
    }
    void i64(int64_t v) { c.serialize(v); }
    void u64(uint64_t v) { c.serialize(v); }
    void f64(double v) { c.serialize(v); }
    void u32(uint32_t v) { c.serialize(v); }
};

// Computes the serialized size with XCDR1 alignment (offset 0 = first byte
// after the encapsulation header).
struct SizeOut {
    size_t off = 0;
    void align(size_t a) { off = (off + a - 1) & ~(a - 1); }
    void str(const std::string& s, size_t) { align(4); off += 4 + s.size() + 1; }
    void i64(int64_t) { align(8); off += 8; }
    void u64(uint64_t) { align(8); off += 8; }
    void f64(double) { align(8); off += 8; }
    void u32(uint32_t) { align(4); off += 4; }
};

struct CdrIn {
    fcdr::Cdr& c;
    std::string str(size_t bound)
    {
        std::string s;
        c.deserialize(s);
        // fastcdr drops the terminating NUL; reject over-long strings.
        if (s.size() > bound) throw std::length_error("string exceeds its bound");
        return s;
    }
    int64_t i64() { int64_t v; c.deserialize(v); return v; }
    uint64_t u64() { uint64_t v; c.deserialize(v); return v; }
    double f64() { double v; c.deserialize(v); return v; }
    uint32_t u32() { uint32_t v; c.deserialize(v); return v; }
    uint32_t seq_len(uint32_t bound)
    {
        uint32_t n = u32();
        if (n > bound) throw std::length_error("sequence exceeds its bound");
        return n;
    }
    uint32_t enum_val(size_t count)
    {
        uint32_t v = u32();
        if (v >= count) throw std::out_of_range("enum value out of range");
        return v;
    }
};

// ------------------------------------------------------------ Shoal types

static const std::vector<std::string> VEHICLE_KIND = {"AUV", "USV", "ASV", "ROV", "GLIDER"};
static const std::vector<std::string> LINK_KIND = {"IP", "ACOUSTIC", "RADIO", "SATELLITE", "TETHER"};
static const std::vector<std::string> TASK_KIND = {
    "GOTO_WAYPOINT", "SURVEY_AREA", "HOLD", "SURFACE", "RETURN_HOME",
    "ABORT", "REQUEST_STATE", "SET_REPORTING_RATE"};

struct StateVector {
    static constexpr const char* TYPE_NAME = "shoal::StateVector";
    std::string vehicle_id;  // @key string<32>
    int64_t timestamp_ms = 0;
    double latitude_deg = 0, longitude_deg = 0, depth_m = 0, altitude_m = 0, speed_mps = 0,
           yaw_deg = 0, pitch_deg = 0, roll_deg = 0, battery_pct = 0;

    template <class W> void write(W& w) const
    {
        w.str(vehicle_id, 32);
        w.i64(timestamp_ms);
        w.f64(latitude_deg);
        w.f64(longitude_deg);
        w.f64(depth_m);
        w.f64(altitude_m);
        w.f64(speed_mps);
        w.f64(yaw_deg);
        w.f64(pitch_deg);
        w.f64(roll_deg);
        w.f64(battery_pct);
    }
    template <class W> void write_key(W& w) const { w.str(vehicle_id, 32); }
    void read(CdrIn& r)
    {
        vehicle_id = r.str(32);
        timestamp_ms = r.i64();
        latitude_deg = r.f64();
        longitude_deg = r.f64();
        depth_m = r.f64();
        altitude_m = r.f64();
        speed_mps = r.f64();
        yaw_deg = r.f64();
        pitch_deg = r.f64();
        roll_deg = r.f64();
        battery_pct = r.f64();
    }
    static StateVector max_sample()
    {
        StateVector s;
        s.vehicle_id.assign(32, 'x');
        return s;
    }
    std::string json() const
    {
        std::ostringstream o;
        o << "{\"vehicle_id\":" << json_str(vehicle_id) << ",\"timestamp_ms\":" << timestamp_ms
          << ",\"latitude_deg\":" << json_num(latitude_deg)
          << ",\"longitude_deg\":" << json_num(longitude_deg) << ",\"depth_m\":" << json_num(depth_m)
          << ",\"altitude_m\":" << json_num(altitude_m) << ",\"speed_mps\":" << json_num(speed_mps)
          << ",\"yaw_deg\":" << json_num(yaw_deg) << ",\"pitch_deg\":" << json_num(pitch_deg)
          << ",\"roll_deg\":" << json_num(roll_deg) << ",\"battery_pct\":" << json_num(battery_pct)
          << "}";
        return o.str();
    }
};

struct VehicleAnnouncement {
    static constexpr const char* TYPE_NAME = "shoal::VehicleAnnouncement";
    std::string vehicle_id;  // @key string<32>
    std::string name;        // string<64>
    uint32_t kind = 0;       // VehicleKind
    std::string vendor;      // string<64>
    std::vector<std::string> capabilities;  // sequence<string<64>, 32>
    std::vector<std::string> sensors;       // sequence<string<64>, 32>
    std::vector<uint32_t> links;            // sequence<LinkKind, 8>
    double max_speed_mps = 0;
    int64_t timestamp_ms = 0;

    template <class W> static void write_strs(W& w, const std::vector<std::string>& v, size_t bound,
                                              size_t str_bound)
    {
        if (v.size() > bound) throw std::length_error("sequence exceeds its bound");
        w.u32(static_cast<uint32_t>(v.size()));
        for (auto& s : v) w.str(s, str_bound);
    }
    template <class W> void write(W& w) const
    {
        w.str(vehicle_id, 32);
        w.str(name, 64);
        w.u32(kind);
        w.str(vendor, 64);
        write_strs(w, capabilities, 32, 64);
        write_strs(w, sensors, 32, 64);
        if (links.size() > 8) throw std::length_error("sequence exceeds its bound");
        w.u32(static_cast<uint32_t>(links.size()));
        for (auto l : links) w.u32(l);
        w.f64(max_speed_mps);
        w.i64(timestamp_ms);
    }
    template <class W> void write_key(W& w) const { w.str(vehicle_id, 32); }
    void read(CdrIn& r)
    {
        vehicle_id = r.str(32);
        name = r.str(64);
        kind = r.enum_val(VEHICLE_KIND.size());
        vendor = r.str(64);
        capabilities.resize(r.seq_len(32));
        for (auto& s : capabilities) s = r.str(64);
        sensors.resize(r.seq_len(32));
        for (auto& s : sensors) s = r.str(64);
        links.resize(r.seq_len(8));
        for (auto& l : links) l = r.enum_val(LINK_KIND.size());
        max_speed_mps = r.f64();
        timestamp_ms = r.i64();
    }
    static VehicleAnnouncement max_sample()
    {
        VehicleAnnouncement s;
        s.vehicle_id.assign(32, 'x');
        s.name.assign(64, 'x');
        s.vendor.assign(64, 'x');
        s.capabilities.assign(32, std::string(64, 'x'));
        s.sensors.assign(32, std::string(64, 'x'));
        s.links.assign(8, 0);
        return s;
    }
    static std::string json_strs(const std::vector<std::string>& v)
    {
        std::string o = "[";
        for (size_t i = 0; i < v.size(); ++i) o += (i ? "," : "") + json_str(v[i]);
        return o + "]";
    }
    std::string json() const
    {
        std::ostringstream o;
        o << "{\"vehicle_id\":" << json_str(vehicle_id) << ",\"name\":" << json_str(name)
          << ",\"kind\":" << json_str(VEHICLE_KIND.at(kind)) << ",\"vendor\":" << json_str(vendor)
          << ",\"capabilities\":" << json_strs(capabilities) << ",\"sensors\":" << json_strs(sensors)
          << ",\"links\":[";
        for (size_t i = 0; i < links.size(); ++i) o << (i ? "," : "") << json_str(LINK_KIND.at(links[i]));
        o << "],\"max_speed_mps\":" << json_num(max_speed_mps) << ",\"timestamp_ms\":" << timestamp_ms
          << "}";
        return o.str();
    }
};

struct GeoPoint {
    double latitude_deg = 0, longitude_deg = 0;
};

struct TaskAssignment {
    static constexpr const char* TYPE_NAME = "shoal::TaskAssignment";
    std::string task_id;     // @key string<64>
    std::string mission_id;  // string<64>
    std::string vehicle_id;  // string<32>
    int64_t issued_ms = 0;
    uint32_t kind = 0;       // TaskKind
    std::vector<GeoPoint> area;  // sequence<GeoPoint, 256>
    double depth_m = 0, altitude_m = 0, speed_mps = 0, line_spacing_m = 0, duration_s = 0, rate_hz = 0;
    uint64_t issue_seq = 0;
    int64_t expires_ms = 0;
    uint64_t lease_term = 0;   // 0 = issued without a command lease
    std::string lease_holder;  // string<32>; empty when lease_term is 0

    template <class W> void write(W& w) const
    {
        w.str(task_id, 64);
        w.str(mission_id, 64);
        w.str(vehicle_id, 32);
        w.i64(issued_ms);
        w.u32(kind);
        if (area.size() > 256) throw std::length_error("sequence exceeds its bound");
        w.u32(static_cast<uint32_t>(area.size()));
        for (auto& p : area) {
            w.f64(p.latitude_deg);
            w.f64(p.longitude_deg);
        }
        w.f64(depth_m);
        w.f64(altitude_m);
        w.f64(speed_mps);
        w.f64(line_spacing_m);
        w.f64(duration_s);
        w.f64(rate_hz);
        w.u64(issue_seq);
        w.i64(expires_ms);
        w.u64(lease_term);  // aligned to 8 like issue_seq (it follows an int64: no padding)
        w.str(lease_holder, 32);
    }
    template <class W> void write_key(W& w) const { w.str(task_id, 64); }
    void read(CdrIn& r)
    {
        task_id = r.str(64);
        mission_id = r.str(64);
        vehicle_id = r.str(32);
        issued_ms = r.i64();
        kind = r.enum_val(TASK_KIND.size());
        area.resize(r.seq_len(256));
        for (auto& p : area) {
            p.latitude_deg = r.f64();
            p.longitude_deg = r.f64();
        }
        depth_m = r.f64();
        altitude_m = r.f64();
        speed_mps = r.f64();
        line_spacing_m = r.f64();
        duration_s = r.f64();
        rate_hz = r.f64();
        issue_seq = r.u64();
        expires_ms = r.i64();
        lease_term = r.u64();
        lease_holder = r.str(32);
    }
    static TaskAssignment max_sample()
    {
        TaskAssignment s;
        s.task_id.assign(64, 'x');
        s.mission_id.assign(64, 'x');
        s.vehicle_id.assign(32, 'x');
        s.area.assign(256, GeoPoint{});
        s.lease_holder.assign(32, 'x');
        return s;
    }
    std::string json() const
    {
        std::ostringstream o;
        o << "{\"task_id\":" << json_str(task_id) << ",\"mission_id\":" << json_str(mission_id)
          << ",\"vehicle_id\":" << json_str(vehicle_id) << ",\"issued_ms\":" << issued_ms
          << ",\"kind\":" << json_str(TASK_KIND.at(kind)) << ",\"area\":[";
        for (size_t i = 0; i < area.size(); ++i)
            o << (i ? "," : "") << "{\"latitude_deg\":" << json_num(area[i].latitude_deg)
              << ",\"longitude_deg\":" << json_num(area[i].longitude_deg) << "}";
        o << "],\"depth_m\":" << json_num(depth_m) << ",\"altitude_m\":" << json_num(altitude_m)
          << ",\"speed_mps\":" << json_num(speed_mps) << ",\"line_spacing_m\":" << json_num(line_spacing_m)
          << ",\"duration_s\":" << json_num(duration_s) << ",\"rate_hz\":" << json_num(rate_hz)
          << ",\"issue_seq\":" << issue_seq << ",\"expires_ms\":" << expires_ms
          << ",\"lease_term\":" << lease_term << ",\"lease_holder\":" << json_str(lease_holder) << "}";
        return o.str();
    }
};

// -------------------------------------------------- TopicDataType (by hand)

template <class T>
class ShoalPubSubType : public TopicDataType {
public:
    ShoalPubSubType()
    {
        setName(T::TYPE_NAME);
        T big = T::max_sample();
        SizeOut s;
        big.write(s);
        m_typeSize = static_cast<uint32_t>(s.off + 4 /* encapsulation */ + 8 /* slack */);
        SizeOut k;
        big.write_key(k);
        key_max_size_ = k.off;
        m_isGetKeyDefined = true;
        key_buffer_.resize(key_max_size_ + 8);
        // We register no TypeObject / TypeInformation: peers match on the type name.
        auto_fill_type_object(false);
        auto_fill_type_information(false);
    }

    bool serialize(void* data, SerializedPayload_t* payload) override
    {
        const T* p = static_cast<const T*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->max_size);
        fcdr::Cdr ser(buf, fcdr::Cdr::LITTLE_ENDIANNESS, fcdr::Cdr::DDS_CDR);
        payload->encapsulation = CDR_LE;
        try {
            ser.serialize_encapsulation();  // 00 01 00 00: CDR_LE, options 0
            CdrOut w{ser};
            p->write(w);
        } catch (const std::exception& e) {
            log(std::string("serialize failed: ") + e.what());
            return false;
        }
        payload->length = static_cast<uint32_t>(ser.getSerializedDataLength());
        return true;
    }

    bool deserialize(SerializedPayload_t* payload, void* data) override
    {
        T* p = static_cast<T*>(data);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(payload->data), payload->length);
        fcdr::Cdr de(buf, fcdr::Cdr::DEFAULT_ENDIAN, fcdr::Cdr::DDS_CDR);
        try {
            de.read_encapsulation();  // sets endianness from the header (CDR_LE / CDR_BE)
            // read_encapsulation accepts the PL_CDR variants too; Shoal's types are final.
            if (de.getDDSCdrPlFlag() != fcdr::Cdr::DDS_CDR_WITHOUT_PL) {
                log("rejecting a PL_CDR sample: Shoal types are @final (plain CDR)");
                return false;
            }
            payload->encapsulation = de.endianness() == fcdr::Cdr::BIG_ENDIANNESS ? CDR_BE : CDR_LE;
            CdrIn r{de};
            p->read(r);
        } catch (const std::exception& e) {
            log(std::string("deserialize failed: ") + e.what());
            return false;
        }
        return true;
    }

    std::function<uint32_t()> getSerializedSizeProvider(void* data) override
    {
        return [data]() -> uint32_t {
            SizeOut s;
            static_cast<const T*>(data)->write(s);
            return static_cast<uint32_t>(s.off + 4);
        };
    }

    void* createData() override { return new T(); }
    void deleteData(void* data) override { delete static_cast<T*>(data); }

    // RTPS 9.6.3.8: key members as big-endian plain CDR (no encapsulation);
    // MD5 of it if the maximum key size is > 16 bytes, else zero-padded.
    bool getKey(void* data, InstanceHandle_t* handle, bool force_md5 = false) override
    {
        const T* p = static_cast<const T*>(data);
        std::fill(key_buffer_.begin(), key_buffer_.end(), 0);
        fcdr::FastBuffer buf(reinterpret_cast<char*>(key_buffer_.data()), key_buffer_.size());
        fcdr::Cdr ser(buf, fcdr::Cdr::BIG_ENDIANNESS, fcdr::Cdr::CORBA_CDR);
        CdrOut w{ser};
        p->write_key(w);
        size_t len = ser.getSerializedDataLength();
        if (force_md5 || key_max_size_ > 16) {
            ::MD5 md5;  // Fast DDS 2.9 declares MD5 in the global namespace
            md5.init();
            md5.update(reinterpret_cast<const unsigned char*>(key_buffer_.data()),
                       static_cast<unsigned int>(len));
            md5.finalize();
            for (int i = 0; i < 16; ++i) handle->value[i] = md5.digest[i];
        } else {
            for (int i = 0; i < 16; ++i) handle->value[i] = key_buffer_[i];
        }
        return true;
    }

private:
    size_t key_max_size_ = 0;
    std::vector<unsigned char> key_buffer_;
};

// ------------------------------------------------------------------ QoS

static DataWriterQos writer_qos(Publisher* pub, bool transient_local, int32_t depth)
{
    DataWriterQos q = pub->get_default_datawriter_qos();
    q.reliability().kind = RELIABLE_RELIABILITY_QOS;
    q.durability().kind = transient_local ? TRANSIENT_LOCAL_DURABILITY_QOS : VOLATILE_DURABILITY_QOS;
    q.history().kind = KEEP_LAST_HISTORY_QOS;
    q.history().depth = depth;
    // A peer writes one instance; KEEP_LAST depth bounds it.
    q.resource_limits().max_instances = 10;
    q.resource_limits().max_samples_per_instance = depth;
    q.resource_limits().max_samples = 10 * depth;
    q.representation().m_value.clear();
    q.representation().m_value.push_back(XCDR_DATA_REPRESENTATION);  // plain XCDR1 CDR
    q.publish_mode().kind = SYNCHRONOUS_PUBLISH_MODE;
    return q;
}

static DataReaderQos reader_qos(Subscriber* sub, bool transient_local, int32_t depth)
{
    DataReaderQos q = sub->get_default_datareader_qos();
    q.reliability().kind = RELIABLE_RELIABILITY_QOS;
    q.durability().kind = transient_local ? TRANSIENT_LOCAL_DURABILITY_QOS : VOLATILE_DURABILITY_QOS;
    q.history().kind = KEEP_LAST_HISTORY_QOS;
    q.history().depth = depth;
    // Room for many vehicles / tasks (instances), KEEP_LAST depth each.
    q.resource_limits().max_instances = 200;
    q.resource_limits().max_samples_per_instance = depth;
    q.resource_limits().max_samples = 200 * depth;
    q.type_consistency().representation.m_value.clear();
    q.type_consistency().representation.m_value.push_back(XCDR_DATA_REPRESENTATION);
    return q;
}

static const char* TOPIC_STATE = "shoal/state_vector";
static const char* TOPIC_ANNOUNCEMENT = "shoal/vehicle_announcement";
static const char* TOPIC_TASK = "shoal/task_assignment";
static const double MATCH_TIMEOUT_S = 20.0;

// Secure-test options (all empty: the peer as it always was).
struct SecOpts {
    std::string security;        // enclave directory
    std::string partition;       // writers' Publisher partition
    std::string read_partition;  // readers' Subscriber partition
};

// "file://" URI of an enclave file, absolute (Fast DDS strips "file://").
static std::string enclave_uri(const std::string& dir, const char* file)
{
    std::string path = dir + "/" + file;
    std::unique_ptr<char, decltype(&std::free)> abs(realpath(path.c_str(), nullptr), &std::free);
    if (!abs) throw std::runtime_error("security: cannot read " + path);
    return std::string("file://") + abs.get();
}

// OMG DDS Security 1.1 builtin plugins, configured as Fast DDS documents them.
static void add_security(DomainParticipantQos& pq, const std::string& dir)
{
    auto& p = pq.properties().properties();
    p.emplace_back("dds.sec.auth.plugin", "builtin.PKI-DH");
    p.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_ca", enclave_uri(dir, "identity_ca.cert.pem"));
    p.emplace_back("dds.sec.auth.builtin.PKI-DH.identity_certificate", enclave_uri(dir, "cert.pem"));
    p.emplace_back("dds.sec.auth.builtin.PKI-DH.private_key", enclave_uri(dir, "key.pem"));
    p.emplace_back("dds.sec.access.plugin", "builtin.Access-Permissions");
    p.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions_ca",
                   enclave_uri(dir, "permissions_ca.cert.pem"));
    p.emplace_back("dds.sec.access.builtin.Access-Permissions.governance", enclave_uri(dir, "governance.p7s"));
    p.emplace_back("dds.sec.access.builtin.Access-Permissions.permissions", enclave_uri(dir, "permissions.p7s"));
    p.emplace_back("dds.sec.crypto.plugin", "builtin.AES-GCM-GMAC");
}

struct Peer {
    DomainParticipant* dp = nullptr;
    Publisher* pub = nullptr;
    Subscriber* sub = nullptr;
    std::map<std::string, Topic*> topics;

    explicit Peer(int domain, const SecOpts& so = SecOpts())
    {
        DomainParticipantQos pq = PARTICIPANT_QOS_DEFAULT;
        pq.name("shoal-interop-fastdds");
        // UDPv4 only: no shared-memory transport, so the peer behaves (and
        // announces locators) like any networked DDS; other vendors would only
        // see Fast DDS's SHM locators (kind 16) as unreachable.
        pq.transport().use_builtin_transports = false;
        pq.transport().user_transports.push_back(std::make_shared<UDPv4TransportDescriptor>());
        if (!so.security.empty()) {
            // Fast DDS logs (e.g. access-control refusals) go to stdout by default:
            // keep stdout for data and "attack" lines.
            auto consumer = std::make_unique<eprosima::fastdds::dds::StdoutErrConsumer>();
            consumer->stderr_threshold(eprosima::fastdds::dds::Log::Kind::Info);
            eprosima::fastdds::dds::Log::ClearConsumers();
            eprosima::fastdds::dds::Log::RegisterConsumer(std::move(consumer));
            add_security(pq, so.security);
            log("security: DDS Security builtin plugins, enclave " + so.security);
        }
        dp = DomainParticipantFactory::get_instance()->create_participant(domain, pq);
        if (!dp) throw std::runtime_error("create_participant failed");
        if (so.partition.empty()) {
            pub = dp->create_publisher(PUBLISHER_QOS_DEFAULT);
        } else {
            PublisherQos q = dp->get_default_publisher_qos();
            q.partition().push_back(so.partition.c_str());
            pub = dp->create_publisher(q);
        }
        if (so.read_partition.empty()) {
            sub = dp->create_subscriber(SUBSCRIBER_QOS_DEFAULT);
        } else {
            SubscriberQos q = dp->get_default_subscriber_qos();
            q.partition().push_back(so.read_partition.c_str());
            sub = dp->create_subscriber(q);
        }
        if (!pub || !sub) throw std::runtime_error("create_publisher/subscriber failed");
    }
    ~Peer()
    {
        if (dp) {
            dp->delete_contained_entities();
            DomainParticipantFactory::get_instance()->delete_participant(dp);
        }
    }
    template <class T> Topic* topic(const char* name)
    {
        auto it = topics.find(name);
        if (it != topics.end()) return it->second;
        TypeSupport ts(new ShoalPubSubType<T>());
        if (ts.register_type(dp) != ReturnCode_t::RETCODE_OK &&
            dp->find_type(T::TYPE_NAME).empty())
            throw std::runtime_error(std::string("register_type failed: ") + T::TYPE_NAME);
        Topic* t = dp->create_topic(name, T::TYPE_NAME, TOPIC_QOS_DEFAULT);
        if (!t) throw std::runtime_error(std::string("create_topic failed: ") + name);
        topics[name] = t;
        return t;
    }
    template <class T> DataWriter* writer(const char* name, bool tl, int32_t depth)
    {
        DataWriter* w = pub->create_datawriter(topic<T>(name), writer_qos(pub, tl, depth));
        if (!w) throw std::runtime_error(std::string("create_datawriter failed: ") + name);
        return w;
    }
    template <class T> DataReader* reader(const char* name, bool tl, int32_t depth)
    {
        DataReader* r = sub->create_datareader(topic<T>(name), reader_qos(sub, tl, depth));
        if (!r) throw std::runtime_error(std::string("create_datareader failed: ") + name);
        return r;
    }
};

static bool wait_matched(DataWriter* w, double timeout_s)
{
    auto end = std::chrono::steady_clock::now() +
               std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
    while (std::chrono::steady_clock::now() < end && !g_stop) {
        PublicationMatchedStatus st;
        if (w->get_publication_matched_status(st) == ReturnCode_t::RETCODE_OK && st.current_count > 0)
            return true;
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return false;
}

template <class T> static std::vector<T> take_valid(DataReader* r, double wait_s)
{
    std::vector<T> out;
    r->wait_for_unread_message(eprosima::fastrtps::Duration_t(wait_s));
    T s;
    SampleInfo info;
    while (r->take_next_sample(&s, &info) == ReturnCode_t::RETCODE_OK) {
        if (info.valid_data) out.push_back(s);
    }
    return out;
}

// ------------------------------------------------------------ samples

static VehicleAnnouncement make_announcement(const std::string& id)
{
    VehicleAnnouncement a;
    a.vehicle_id = id;
    a.name = std::string(PEER) + " interop vehicle " + id;
    a.kind = 0;  // AUV
    a.vendor = PEER;
    a.capabilities = {"goto", "survey"};
    a.sensors = {"ctd"};
    a.links = {0};  // IP
    a.max_speed_mps = 2.0;
    a.timestamp_ms = now_ms();
    return a;
}

static StateVector make_state(const std::string& id, int i)
{
    StateVector s;
    s.vehicle_id = id;
    s.timestamp_ms = now_ms();
    s.latitude_deg = 43.0 + i * 1e-5;
    s.longitude_deg = 5.9;
    s.depth_m = 10.0;
    s.altitude_m = -1.0;
    s.speed_mps = 1.0;
    s.yaw_deg = 90.0;
    s.pitch_deg = 0.0;
    s.roll_deg = 0.0;
    s.battery_pct = 90.0 - i * 0.01;
    return s;
}

static TaskAssignment make_task(const std::string& task_id, const std::string& vehicle_id)
{
    TaskAssignment t;
    t.task_id = task_id;
    t.mission_id = "";
    t.vehicle_id = vehicle_id;
    t.issued_ms = now_ms();
    t.kind = 0;  // GOTO_WAYPOINT
    t.area = {GeoPoint{43.0, 5.9}};
    t.depth_m = 10.0;
    t.altitude_m = -1.0;
    t.speed_mps = 1.5;
    t.issue_seq = 1;
    t.expires_ms = t.issued_ms + 600000;
    // As a station without a command lease sends it (no federation, or the lease off).
    t.lease_term = 0;
    t.lease_holder = "";
    return t;
}

// ------------------------------------------------------------ arguments

struct Args {
    std::string cmd;
    std::vector<std::string> pos;
    std::map<std::string, std::string> opt;
    int domain = 0;

    bool has(const std::string& k) const { return opt.count(k) != 0; }
    std::string get(const std::string& k, const std::string& def = "") const
    {
        auto it = opt.find(k);
        return it == opt.end() ? def : it->second;
    }
    std::string need(const std::string& k) const
    {
        auto it = opt.find(k);
        if (it == opt.end()) throw std::invalid_argument("missing --" + k);
        return it->second;
    }
    double num(const std::string& k, double def) const
    {
        auto it = opt.find(k);
        return it == opt.end() ? def : std::stod(it->second);
    }
};

static void usage()
{
    std::cerr <<
        "usage: fastdds_peer [--domain D] <command> [options]\n"
        "  publish-state   --vehicle-id ID [--count N] [--rate HZ] [--linger S] [--settle S]\n"
        "  subscribe-task  --vehicle-id ID [--expect N] [--timeout S]\n"
        "  publish-task    --vehicle-id ID --task-id T [--linger S] [--wait-match S]\n"
        "  subscribe-state [--expect N] [--timeout S] [--vehicle-id ID] [--expect-announcements K]\n"
        "  encode-demo <StateVector|VehicleAnnouncement|TaskAssignment>\n"
        "  key-hash <StateVector|VehicleAnnouncement|TaskAssignment> <key>\n"
        "secure tests: [--security ENCLAVE_DIR] [--partition P] [--read-partition P]\n"
        "              [--attack] [--match-timeout S]\n";
}

static Args parse(int argc, char** argv)
{
    Args a;
    for (int i = 1; i < argc; ++i) {
        std::string s = argv[i];
        if (s == "-h" || s == "--help") {
            usage();
            std::exit(0);
        }
        if (s.rfind("--", 0) == 0) {
            std::string k = s.substr(2), v;
            auto eq = k.find('=');
            if (k == "attack") {  // the one flag without a value
                a.opt[k] = "1";
                continue;
            }
            if (eq != std::string::npos) {
                v = k.substr(eq + 1);
                k = k.substr(0, eq);
            } else {
                if (i + 1 >= argc) throw std::invalid_argument("option --" + k + " needs a value");
                v = argv[++i];
            }
            a.opt[k] = v;
        } else if (a.cmd.empty()) {
            a.cmd = s;
        } else {
            a.pos.push_back(s);
        }
    }
    if (a.opt.count("domain")) a.domain = std::stoi(a.opt["domain"]);
    return a;
}

// ------------------------------------------------------------ commands

static SecOpts sec_opts(const Args& a)
{
    SecOpts so;
    so.security = a.get("security");
    so.partition = a.get("partition");
    so.read_partition = a.get("read-partition");
    return so;
}

// --attack: publish what the remote side's access control should refuse, and
// report every step on stdout instead of giving up ("attack ..." lines).
static std::string partition_desc(const Args& a)
{
    std::string p = a.get("partition");
    return p.empty() ? "(default partition)" : "partition=" + p;
}

template <class T> static DataWriter* attack_writer(Peer& p, const Args& a, const char* topic, bool tl,
                                                    int32_t depth)
{
    try {
        DataWriter* w = p.writer<T>(topic, tl, depth);
        emit(std::string("attack writer ") + topic + " " + partition_desc(a) + ": created");
        return w;
    } catch (const std::exception& e) {
        emit(std::string("attack writer ") + topic + " " + partition_desc(a) +
             ": refused locally (" + e.what() + ")");
        return nullptr;
    }
}

static int matched_count(DataWriter* w)
{
    PublicationMatchedStatus st;
    if (w->get_publication_matched_status(st) != ReturnCode_t::RETCODE_OK) return -1;
    return st.current_count;
}

static void attack_report_delivery(DataWriter* w, const char* topic, int ok, int failed, double linger)
{
    emit(std::string("attack write ") + topic + " ok=" + std::to_string(ok) +
         " failed=" + std::to_string(failed));
    bool acked = w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(linger)) ==
                 ReturnCode_t::RETCODE_OK;
    emit(std::string("attack matched ") + std::to_string(matched_count(w)) + " readers on " + topic +
         "; acknowledged by all: " + (acked ? "yes" : "no"));
}

static int cmd_attack_state(const Args& a)
{
    std::string id = a.need("vehicle-id");
    int count = static_cast<int>(a.num("count", 10));
    double rate = a.num("rate", 10.0), linger = a.num("linger", 3.0), settle = a.num("settle", 1.0);
    double match_timeout = a.num("match-timeout", MATCH_TIMEOUT_S);
    Peer p(a.domain, sec_opts(a));
    emit("attack publish-state vehicle_id=" + id + " " + partition_desc(a) + " enclave=" +
         a.get("security", "(none)"));
    DataWriter* aw = attack_writer<VehicleAnnouncement>(p, a, TOPIC_ANNOUNCEMENT, true, 1);
    if (aw) {
        VehicleAnnouncement ann = make_announcement(id);
        bool ok = static_cast<bool>(aw->write(&ann));
        wait_matched(aw, std::min(match_timeout, 5.0));
        attack_report_delivery(aw, TOPIC_ANNOUNCEMENT, ok ? 1 : 0, ok ? 0 : 1, std::min(linger, 5.0));
    }
    DataWriter* w = attack_writer<StateVector>(p, a, TOPIC_STATE, false, 100);
    int sent = 0, failed = 0;
    if (w) {
        bool m = wait_matched(w, match_timeout);
        if (g_stop) return g_stop_code;
        emit(std::string("attack matched ") + std::to_string(matched_count(w)) + " readers on " +
             TOPIC_STATE + (m ? "" : " (none within --match-timeout)"));
        if (!sleep_unless_stopped(settle)) return g_stop_code;
        double period = rate > 0 ? 1.0 / rate : 0.0;
        for (int i = 0; i < count && !g_stop; ++i) {
            StateVector s = make_state(id, i);
            if (w->write(&s)) ++sent; else ++failed;
            if (i + 1 < count && !sleep_unless_stopped(period)) break;
        }
        if (g_stop) return g_stop_code;
        attack_report_delivery(w, TOPIC_STATE, sent, failed, linger);
        sleep_unless_stopped(linger);
    }
    emit("published " + std::to_string(sent));
    return g_stop ? g_stop_code.load() : 0;
}

static int cmd_attack_task(const Args& a)
{
    std::string id = a.need("vehicle-id"), task = a.need("task-id");
    double linger = a.num("linger", 3.0), wait_match = a.num("wait-match", 0.0);
    Peer p(a.domain, sec_opts(a));
    emit("attack publish-task task_id=" + task + " vehicle_id=" + id + " " + partition_desc(a) +
         " enclave=" + a.get("security", "(none)"));
    DataWriter* w = attack_writer<TaskAssignment>(p, a, TOPIC_TASK, true, 100);
    int sent = 0;
    if (w) {
        if (wait_match > 0) wait_matched(w, wait_match);
        if (g_stop) return g_stop_code;
        emit(std::string("attack matched ") + std::to_string(matched_count(w)) + " readers on " + TOPIC_TASK);
        TaskAssignment t = make_task(task, id);
        bool ok = static_cast<bool>(w->write(&t));
        sent = ok ? 1 : 0;
        attack_report_delivery(w, TOPIC_TASK, sent, 1 - sent, linger);
        sleep_unless_stopped(linger);
    }
    emit("published " + std::to_string(sent));
    return g_stop ? g_stop_code.load() : 0;
}

static int cmd_publish_state(const Args& a)
{
    std::string id = a.need("vehicle-id");
    int count = static_cast<int>(a.num("count", 10));
    double rate = a.num("rate", 10.0), linger = a.num("linger", 3.0), settle = a.num("settle", 1.0);
    Peer p(a.domain, sec_opts(a));
    DataWriter* aw = p.writer<VehicleAnnouncement>(TOPIC_ANNOUNCEMENT, true, 1);
    VehicleAnnouncement ann = make_announcement(id);
    if (!aw->write(&ann)) {
        log("announcement write failed");
        return 1;
    }
    log("announced " + id);
    // A station rejects state from a vehicle it has no announcement of: let the
    // announcement reach every matched reader first (a busy host can take seconds).
    if (wait_matched(aw, MATCH_TIMEOUT_S) &&
        aw->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(10.0)) != ReturnCode_t::RETCODE_OK)
        log("announcement not acknowledged within 10 s; publishing anyway");
    DataWriter* w = p.writer<StateVector>(TOPIC_STATE, false, 100);
    if (!wait_matched(w, MATCH_TIMEOUT_S)) {
        if (g_stop) return g_stop_code;
        log("no StateVector reader matched within 20 s");
        return 1;
    }
    log("StateVector reader matched");
    // The writer can see the reader before the reader has discovered the
    // writer; a VOLATILE reader drops samples written in that window.
    if (!sleep_unless_stopped(settle)) return g_stop_code;
    double period = rate > 0 ? 1.0 / rate : 0.0;
    int sent = 0;
    for (int i = 0; i < count && !g_stop; ++i) {
        StateVector s = make_state(id, i);
        if (!w->write(&s)) {
            log("StateVector write failed");
            return 1;
        }
        ++sent;
        if (i + 1 < count && !sleep_unless_stopped(period)) break;
    }
    if (!g_stop) {
        if (w->wait_for_acknowledgments(eprosima::fastrtps::Duration_t(linger)) !=
            ReturnCode_t::RETCODE_OK)
            log("not all samples acknowledged before --linger ran out");
        sleep_unless_stopped(linger);
    }
    emit("published " + std::to_string(sent));
    return sent == count ? 0 : g_stop_code.load();
}

static int cmd_publish_task(const Args& a)
{
    std::string id = a.need("vehicle-id"), task = a.need("task-id");
    double linger = a.num("linger", 3.0), wait_match = a.num("wait-match", 0.0);
    Peer p(a.domain, sec_opts(a));
    DataWriter* w = p.writer<TaskAssignment>(TOPIC_TASK, true, 100);
    if (wait_match > 0 && !wait_matched(w, wait_match))
        log("no TaskAssignment reader matched yet; publishing anyway (transient-local)");
    TaskAssignment t = make_task(task, id);
    if (!w->write(&t)) {
        log("TaskAssignment write failed");
        return 1;
    }
    log("published task " + task + " for " + id + "; lingering " + json_num(linger) + " s");
    sleep_unless_stopped(linger);
    emit("published 1");
    return 0;
}

static int cmd_subscribe_task(const Args& a)
{
    std::string id = a.need("vehicle-id");
    int expect = static_cast<int>(a.num("expect", 1));
    double timeout = a.num("timeout", 30.0);
    Peer p(a.domain, sec_opts(a));
    DataReader* r = p.reader<TaskAssignment>(TOPIC_TASK, true, 100);
    auto end = std::chrono::steady_clock::now() +
               std::chrono::milliseconds(static_cast<int64_t>(timeout * 1000));
    int got = 0;
    while (got < expect) {
        if (g_stop) return g_stop_code;
        if (std::chrono::steady_clock::now() > end) {
            log("timeout: received " + std::to_string(got) + " of " + std::to_string(expect) +
                " TaskAssignments for " + id);
            return 1;
        }
        for (auto& t : take_valid<TaskAssignment>(r, 0.1)) {
            if (t.vehicle_id == id && got < expect) {
                emit(t.json());
                ++got;
            }
        }
    }
    return 0;
}

static int cmd_subscribe_state(const Args& a)
{
    int expect = static_cast<int>(a.num("expect", 1));
    int expect_ann = static_cast<int>(a.num("expect-announcements", 0));
    double timeout = a.num("timeout", 30.0);
    std::string id = a.get("vehicle-id");
    Peer p(a.domain, sec_opts(a));
    DataReader* r = p.reader<StateVector>(TOPIC_STATE, false, 100);
    DataReader* ra = expect_ann > 0 ? p.reader<VehicleAnnouncement>(TOPIC_ANNOUNCEMENT, true, 1) : nullptr;
    auto end = std::chrono::steady_clock::now() +
               std::chrono::milliseconds(static_cast<int64_t>(timeout * 1000));
    int got = 0, got_ann = 0;
    while (got < expect || got_ann < expect_ann) {
        if (g_stop) return g_stop_code;
        if (std::chrono::steady_clock::now() > end) {
            log("timeout: received " + std::to_string(got) + " of " + std::to_string(expect) +
                " StateVectors, " + std::to_string(got_ann) + " of " + std::to_string(expect_ann) +
                " announcements");
            return 1;
        }
        if (ra) {
            for (auto& s : take_valid<VehicleAnnouncement>(ra, 0.0)) {
                if (id.empty() || s.vehicle_id == id) {
                    emit("announcement " + s.json());
                    ++got_ann;
                }
            }
        }
        for (auto& s : take_valid<StateVector>(r, 0.05)) {
            if ((id.empty() || s.vehicle_id == id) && got < expect) {
                emit(s.json());
                ++got;
            }
        }
    }
    return 0;
}

template <class T> static std::string encode_hex(const T& s)
{
    ShoalPubSubType<T> t;
    std::vector<unsigned char> buf(t.m_typeSize + 16);
    SerializedPayload_t pl(static_cast<uint32_t>(buf.size()));
    T copy = s;
    if (!t.serialize(&copy, &pl)) throw std::runtime_error("serialize failed");
    // Round-trip through deserialize as a self-check.
    T back;
    if (!t.deserialize(&pl, &back) || back.json() != s.json())
        throw std::runtime_error("round trip mismatch");
    return hex(pl.data + 4, pl.length - 4);
}

static int cmd_encode_demo(const Args& a)
{
    if (a.pos.size() != 1) throw std::invalid_argument("encode-demo needs a type name");
    std::string ty = a.pos[0];
    if (ty.rfind("shoal::", 0) == 0) ty = ty.substr(7);
    if (ty == "StateVector") {
        StateVector s = make_state("auv-1", 3);
        s.timestamp_ms = 1700000000123;
        emit(s.json());
        emit(encode_hex(s));
    } else if (ty == "VehicleAnnouncement") {
        VehicleAnnouncement s = make_announcement("auv-1");
        s.timestamp_ms = 1700000000123;
        s.links = {0, 2, 4};
        s.kind = 4;
        emit(s.json());
        emit(encode_hex(s));
    } else if (ty == "TaskAssignment") {
        TaskAssignment s = make_task("task-7", "auv-1");
        s.issued_ms = 1700000000123;
        s.expires_ms = 1700000600123;
        s.mission_id = "m1";
        s.kind = 1;
        s.area = {GeoPoint{43.0, 5.9}, GeoPoint{43.001, 5.9}, GeoPoint{43.001, 5.901}};
        s.line_spacing_m = 25.0;
        // A leased task, so the codec check covers a non-empty holder after the u64.
        s.lease_term = 3;
        s.lease_holder = "ship-1";
        emit(s.json());
        emit(encode_hex(s));
    } else {
        throw std::invalid_argument("unknown type " + ty);
    }
    return 0;
}

template <class T> static std::string key_hash(T& s)
{
    ShoalPubSubType<T> t;
    InstanceHandle_t h;
    t.getKey(&s, &h);
    return hex(h.value, 16);
}

static int cmd_key_hash(const Args& a)
{
    if (a.pos.size() != 2) throw std::invalid_argument("key-hash needs <Type> <key>");
    std::string ty = a.pos[0];
    if (ty.rfind("shoal::", 0) == 0) ty = ty.substr(7);
    if (ty == "StateVector") {
        StateVector s;
        s.vehicle_id = a.pos[1];
        emit(key_hash(s));
    } else if (ty == "VehicleAnnouncement") {
        VehicleAnnouncement s;
        s.vehicle_id = a.pos[1];
        emit(key_hash(s));
    } else if (ty == "TaskAssignment") {
        TaskAssignment s;
        s.task_id = a.pos[1];
        emit(key_hash(s));
    } else {
        throw std::invalid_argument("unknown type " + ty);
    }
    return 0;
}

int main(int argc, char** argv)
{
    std::signal(SIGINT, on_signal);
    std::signal(SIGTERM, on_signal);
    try {
        Args a = parse(argc, argv);
        if (a.cmd == "publish-state") return a.has("attack") ? cmd_attack_state(a) : cmd_publish_state(a);
        if (a.cmd == "publish-task") return a.has("attack") ? cmd_attack_task(a) : cmd_publish_task(a);
        if (a.cmd == "subscribe-task") return cmd_subscribe_task(a);
        if (a.cmd == "subscribe-state") return cmd_subscribe_state(a);
        if (a.cmd == "encode-demo") return cmd_encode_demo(a);
        if (a.cmd == "key-hash") return cmd_key_hash(a);
        usage();
        return 2;
    } catch (const std::invalid_argument& e) {
        log(std::string("error: ") + e.what());
        usage();
        return 2;
    } catch (const std::exception& e) {
        log(std::string("error: ") + e.what());
        return 1;
    }
}
