// A Fast DDS peer of the mode360 node, used by tests/node/fastdds.rs: the middleware most
// ROS 2 users run (the default of Humble and Jazzy). The participant keeps Fast DDS's default
// QoS and builtin transports (shared memory plus UDPv4), as a stock ROS 2 node would; types
// come from Ros2Msgs.idl through fastddsgen (rosidl's DDS names, topics `rt/<name>`),
// independently of mode360's code.
//
//   fastdds_peer subscribe --domain D [--depth-topic /depth] [--points-topic /points]
//                          [--max-depth-m 1000] [--timeout-s 30]
//       Prints `ready TRANSPORTS` once both readers are matched with a writer, then waits for
//       a `depth` image and a `points` cloud with the same stamp, checks them against each
//       other and prints `result {json}` (the same summary as tests/interop/cyclone_peer.py).
//       QoS as the node's outputs: reliable, volatile, keep last 10.
//
//   fastdds_peer publish --domain D --width W --height H --camera TOPIC FRAME_ID
//                        [--camera TOPIC FRAME_ID ...] [--timeout-s 30]
//       Prints `ready TRANSPORTS` once every camera writer is matched with a reader, then
//       obeys stdin lines: `publish K STAMP_NS FILE...` sends one raw rgb8 file (W x H x 3
//       bytes) per camera as a sensor_msgs/Image stamped STAMP_NS and prints
//       `published K STAMP_NS`; `quit` (or end of input) exits. QoS as the node's camera
//       subscriptions (sensor data): best effort, volatile, keep last 5.
//
// TRANSPORTS says how the participant's transports are configured
// (`builtin_transports=1 user_transports=0`: the defaults).
//
// Exit status 0 on success; 1 with a message on stderr when something is missing or
// malformed; 2 on bad usage.

#include "Ros2Msgs.h"
#include "Ros2MsgsPubSubTypes.h"

#include <fastdds/dds/domain/DomainParticipant.hpp>
#include <fastdds/dds/domain/DomainParticipantFactory.hpp>
#include <fastdds/dds/publisher/DataWriter.hpp>
#include <fastdds/dds/publisher/Publisher.hpp>
#include <fastdds/dds/publisher/qos/DataWriterQos.hpp>
#include <fastdds/dds/subscriber/DataReader.hpp>
#include <fastdds/dds/subscriber/SampleInfo.hpp>
#include <fastdds/dds/subscriber/Subscriber.hpp>
#include <fastdds/dds/subscriber/qos/DataReaderQos.hpp>
#include <fastdds/dds/topic/Topic.hpp>
#include <fastdds/dds/topic/TypeSupport.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace fdds = eprosima::fastdds::dds;
using sensor_msgs::msg::dds_::Image_;
using sensor_msgs::msg::dds_::Image_PubSubType;
using sensor_msgs::msg::dds_::PointCloud2_;
using sensor_msgs::msg::dds_::PointCloud2_PubSubType;
using std_msgs::msg::dds_::Header_;

namespace {

constexpr std::uint8_t kFloat32 = 7;  // sensor_msgs/PointField datatype
constexpr std::uint64_t kNanos = 1000000000ULL;
constexpr auto kPoll = std::chrono::milliseconds(20);

/// Something missing or malformed: exit status 1.
struct PeerError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

/// Bad command line: exit status 2.
struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

void say(const std::string& line) {
    std::cout << line << std::endl;  // endl flushes: the test reads line by line
}

std::string dds_topic(const std::string& name) {
    if (name.empty() || name[0] != '/') {
        throw PeerError("topic '" + name + "' must be absolute (start with '/')");
    }
    return "rt" + name;
}

std::uint64_t stamp_ns(const Header_& header) {
    return static_cast<std::uint64_t>(header.stamp().sec()) * kNanos + header.stamp().nanosec();
}

std::string fnv1a64(const std::vector<std::uint8_t>& data) {
    std::uint64_t h = 0xcbf29ce484222325ULL;
    for (std::uint8_t b : data) {
        h = (h ^ b) * 0x100000001b3ULL;
    }
    char text[17];
    std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(h));
    return text;
}

/// Ray of pixel (u, v) of a width x height equirectangular image (REP 103 axes: longitude 0
/// at the centre column, +pi/2 is +y; the top row looks up).
void erp_direction(std::size_t u, std::size_t v, std::size_t width, std::size_t height,
                   double out[3]) {
    const double lon = M_PI * (1.0 - 2.0 * (static_cast<double>(u) + 0.5) / width);
    const double lat = M_PI / 2.0 - M_PI * (static_cast<double>(v) + 0.5) / height;
    out[0] = std::cos(lat) * std::cos(lon);
    out[1] = std::cos(lat) * std::sin(lon);
    out[2] = std::sin(lat);
}

bool is_point_range(double r, double max_depth_m) {
    return std::isfinite(r) && r > 0.0 && r < max_depth_m;
}

/// The float32 at `offset` of `data`, stored big-endian when `big_endian`.
float read_f32(const std::vector<std::uint8_t>& data, std::size_t offset, bool big_endian) {
    std::uint8_t b[4];
    std::memcpy(b, data.data() + offset, 4);
    const bool host_big = [] {
        const std::uint16_t one = 1;
        std::uint8_t first;
        std::memcpy(&first, &one, 1);
        return first == 0;
    }();
    if (big_endian != host_big) {
        std::reverse(b, b + 4);
    }
    float f;
    std::memcpy(&f, b, 4);
    return f;
}

std::string json_string(const std::string& s) {
    std::string out = "\"";
    for (char c : s) {
        if (c == '"' || c == '\\') {
            out += '\\';
            out += c;
        } else if (static_cast<unsigned char>(c) < 0x20) {
            char esc[8];
            std::snprintf(esc, sizeof esc, "\\u%04x", static_cast<unsigned>(c));
            out += esc;
        } else {
            out += c;
        }
    }
    return out + "\"";
}

std::string json_number(double x) {
    char text[40];
    std::snprintf(text, sizeof text, "%.9g", x);
    return text;
}

/// What the Rust test asserts on: the depth image's header and size, its finite and
/// point-worthy ranges, and the cloud's layout, count and x y z against range x direction.
std::string summarize(const Image_& depth, const PointCloud2_& cloud, double max_depth_m) {
    if (depth.encoding() != "32FC1") {
        throw PeerError("depth: encoding '" + depth.encoding() + "', expected '32FC1'");
    }
    const std::size_t w = depth.width(), h = depth.height(), step = depth.step();
    const std::vector<std::uint8_t>& data = depth.data();
    if (step < 4 * w || data.size() != h * step) {
        std::ostringstream msg;
        msg << "depth: " << data.size() << " bytes for " << w << "x" << h << " with step "
            << step << " (need " << h * step << ", step >= " << 4 * w << ")";
        throw PeerError(msg.str());
    }
    struct Range {
        std::size_t u, v;
        double r;
    };
    std::size_t finite = 0;
    std::vector<Range> wanted;
    for (std::size_t v = 0; v < h; ++v) {
        for (std::size_t u = 0; u < w; ++u) {
            const double r = read_f32(data, v * step + 4 * u, depth.is_bigendian() != 0);
            if (std::isfinite(r)) {
                ++finite;
            }
            if (is_point_range(r, max_depth_m)) {
                wanted.push_back({u, v, r});
            }
        }
    }

    std::map<std::string, std::uint32_t> offsets;
    for (const auto& f : cloud.fields()) {
        if (f.datatype() == kFloat32 && f.count() == 1) {
            offsets[f.name()] = f.offset();
        }
    }
    const char* axes[3] = {"x", "y", "z"};
    for (const char* axis : axes) {
        if (offsets.count(axis) == 0) {
            throw PeerError(std::string("points: field '") + axis +
                            "' missing or not one float32");
        }
    }
    const std::vector<std::uint8_t>& cdata = cloud.data();
    const std::size_t n_points = static_cast<std::size_t>(cloud.width()) * cloud.height();
    const std::size_t point_step = cloud.point_step();
    if (cdata.size() != n_points * point_step) {
        std::ostringstream msg;
        msg << "points: " << cdata.size() << " bytes for " << n_points << " points of "
            << point_step << " bytes";
        throw PeerError(msg.str());
    }
    for (const char* axis : axes) {
        if (offsets[axis] + 4 > point_step) {
            throw PeerError(std::string("points: field '") + axis + "' beyond point_step");
        }
    }
    double max_err = 0.0;
    std::size_t checked = 0;
    // The node writes one point per point-worthy pixel, row by row.
    for (std::size_t k = 0; k < wanted.size() && k < n_points; ++k) {
        double d[3];
        erp_direction(wanted[k].u, wanted[k].v, w, h, d);
        for (int a = 0; a < 3; ++a) {
            const double got =
                    read_f32(cdata, k * point_step + offsets[axes[a]], cloud.is_bigendian());
            max_err = std::max(max_err, std::fabs(got - wanted[k].r * d[a]));
        }
        ++checked;
    }

    std::ostringstream fields;
    fields << "[";
    for (std::size_t i = 0; i < cloud.fields().size(); ++i) {
        const auto& f = cloud.fields()[i];
        fields << (i ? ", " : "") << "[" << json_string(f.name()) << ", " << f.offset() << ", "
               << static_cast<unsigned>(f.datatype()) << ", " << f.count() << "]";
    }
    fields << "]";

    std::ostringstream out;
    out << "{\"depth\": {"
        << "\"stamp_ns\": \"" << stamp_ns(depth.header()) << "\", "
        << "\"frame_id\": " << json_string(depth.header().frame_id()) << ", "
        << "\"width\": " << w << ", \"height\": " << h << ", "
        << "\"encoding\": " << json_string(depth.encoding()) << ", "
        << "\"step\": " << step << ", "
        << "\"finite_ranges\": " << finite << ", "
        << "\"point_ranges\": " << wanted.size() << ", "
        << "\"fnv1a64\": \"" << fnv1a64(data) << "\"}, "
        << "\"points\": {"
        << "\"stamp_ns\": \"" << stamp_ns(cloud.header()) << "\", "
        << "\"frame_id\": " << json_string(cloud.header().frame_id()) << ", "
        << "\"width\": " << cloud.width() << ", \"height\": " << cloud.height() << ", "
        << "\"point_step\": " << point_step << ", "
        << "\"fields\": " << fields.str() << ", "
        << "\"is_dense\": " << (cloud.is_dense() ? "true" : "false") << ", "
        << "\"checked_points\": " << checked << ", "
        << "\"max_xyz_error_m\": " << json_number(max_err) << ", "
        << "\"fnv1a64\": \"" << fnv1a64(cdata) << "\"}";
    return out.str();
}

/// Waits until `done()`, at most `timeout_s`; throws naming `what` on timeout.
template <typename F>
void wait_until(F done, double timeout_s, const std::string& what) {
    const auto deadline = std::chrono::steady_clock::now() +
                          std::chrono::duration<double>(timeout_s);
    while (!done()) {
        if (std::chrono::steady_clock::now() > deadline) {
            throw PeerError("timed out after " + json_number(timeout_s) + " s waiting for " +
                            what);
        }
        std::this_thread::sleep_for(kPoll);
    }
}

/// A participant on the default QoS (so the default transports: shared memory and UDPv4)
/// that deletes its entities on exit.
class Participant {
public:
    explicit Participant(int domain) {
        auto* factory = fdds::DomainParticipantFactory::get_instance();
        participant_ = factory->create_participant(domain, fdds::PARTICIPANT_QOS_DEFAULT);
        if (participant_ == nullptr) {
            throw PeerError("cannot create a participant in domain " + std::to_string(domain));
        }
    }
    Participant(const Participant&) = delete;
    Participant& operator=(const Participant&) = delete;
    ~Participant() {
        participant_->delete_contained_entities();
        fdds::DomainParticipantFactory::get_instance()->delete_participant(participant_);
    }

    /// How the participant's transports are configured, for the `ready` line:
    /// `builtin_transports=1 user_transports=0` means Fast DDS's defaults (shared memory and
    /// UDPv4).
    std::string transports() const {
        const auto& t = participant_->get_qos().transport();
        return "builtin_transports=" + std::to_string(t.use_builtin_transports ? 1 : 0) +
               " user_transports=" + std::to_string(t.user_transports.size());
    }

    /// Registers `type` (once per name) and returns the topic `name` of it.
    fdds::Topic* topic(const std::string& name, fdds::TypeSupport type) {
        if (participant_->find_type(type.get_type_name()).empty() &&
            type.register_type(participant_) != ReturnCode_t::RETCODE_OK) {
            throw PeerError("cannot register type " + type.get_type_name());
        }
        fdds::Topic* t = participant_->create_topic(name, type.get_type_name(),
                                                   fdds::TOPIC_QOS_DEFAULT);
        if (t == nullptr) {
            throw PeerError("cannot create topic " + name);
        }
        return t;
    }

    fdds::Subscriber* subscriber() {
        if (subscriber_ == nullptr) {
            subscriber_ = participant_->create_subscriber(fdds::SUBSCRIBER_QOS_DEFAULT);
        }
        if (subscriber_ == nullptr) {
            throw PeerError("cannot create a subscriber");
        }
        return subscriber_;
    }

    fdds::Publisher* publisher() {
        if (publisher_ == nullptr) {
            publisher_ = participant_->create_publisher(fdds::PUBLISHER_QOS_DEFAULT);
        }
        if (publisher_ == nullptr) {
            throw PeerError("cannot create a publisher");
        }
        return publisher_;
    }

private:
    fdds::DomainParticipant* participant_ = nullptr;
    fdds::Subscriber* subscriber_ = nullptr;
    fdds::Publisher* publisher_ = nullptr;
};

struct SubscribeArgs {
    int domain = -1;
    std::string depth_topic = "/depth";
    std::string points_topic = "/points";
    double max_depth_m = 1000.0;
    double timeout_s = 30.0;
};

struct Camera {
    std::string topic;
    std::string frame_id;
};

struct PublishArgs {
    int domain = -1;
    std::uint32_t width = 0;
    std::uint32_t height = 0;
    std::vector<Camera> cameras;
    double timeout_s = 30.0;
};

template <typename T>
std::size_t matched(T* endpoint);

template <>
std::size_t matched(fdds::DataReader* reader) {
    fdds::SubscriptionMatchedStatus status;
    reader->get_subscription_matched_status(status);
    return static_cast<std::size_t>(status.current_count);
}

template <>
std::size_t matched(fdds::DataWriter* writer) {
    fdds::PublicationMatchedStatus status;
    writer->get_publication_matched_status(status);
    return static_cast<std::size_t>(status.current_count);
}

void subscribe(const SubscribeArgs& args) {
    Participant dp(args.domain);
    fdds::DataReaderQos qos = fdds::DATAREADER_QOS_DEFAULT;
    qos.reliability().kind = fdds::RELIABLE_RELIABILITY_QOS;
    qos.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
    qos.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
    qos.history().depth = 10;
    fdds::DataReader* depth_reader = dp.subscriber()->create_datareader(
        dp.topic(dds_topic(args.depth_topic), fdds::TypeSupport(new Image_PubSubType())), qos);
    fdds::DataReader* points_reader = dp.subscriber()->create_datareader(
        dp.topic(dds_topic(args.points_topic), fdds::TypeSupport(new PointCloud2_PubSubType())),
        qos);
    if (depth_reader == nullptr || points_reader == nullptr) {
        throw PeerError("cannot create the readers");
    }
    wait_until([&] { return matched(depth_reader) > 0 && matched(points_reader) > 0; },
               args.timeout_s,
               "writers of " + args.depth_topic + " and " + args.points_topic);
    say("ready " + dp.transports());

    std::map<std::uint64_t, Image_> depths;
    std::map<std::uint64_t, PointCloud2_> clouds;
    const auto deadline = std::chrono::steady_clock::now() +
                          std::chrono::duration<double>(args.timeout_s);
    for (;;) {
        fdds::SampleInfo info;
        Image_ image;
        while (depth_reader->take_next_sample(&image, &info) == ReturnCode_t::RETCODE_OK) {
            if (info.valid_data) {
                depths[stamp_ns(image.header())] = image;
            }
        }
        PointCloud2_ cloud;
        while (points_reader->take_next_sample(&cloud, &info) == ReturnCode_t::RETCODE_OK) {
            if (info.valid_data) {
                clouds[stamp_ns(cloud.header())] = cloud;
            }
        }
        for (const auto& [stamp, d] : depths) {
            auto c = clouds.find(stamp);
            if (c != clouds.end()) {
                std::string result = summarize(d, c->second, args.max_depth_m);
                result += ", \"received\": {\"depth\": " + std::to_string(depths.size()) +
                          ", \"points\": " + std::to_string(clouds.size()) + "}}";
                say("result " + result);
                return;
            }
        }
        if (std::chrono::steady_clock::now() > deadline) {
            throw PeerError("timed out after " + json_number(args.timeout_s) + " s: " +
                            std::to_string(depths.size()) + " depth and " +
                            std::to_string(clouds.size()) +
                            " points received, none with a common stamp");
        }
        std::this_thread::sleep_for(kPoll);
    }
}

std::vector<std::uint8_t> read_file(const std::string& path, std::size_t expected) {
    std::ifstream in(path, std::ios::binary);
    if (!in) {
        throw PeerError(path + ": cannot open");
    }
    std::vector<std::uint8_t> data((std::istreambuf_iterator<char>(in)),
                                   std::istreambuf_iterator<char>());
    if (data.size() != expected) {
        throw PeerError(path + ": " + std::to_string(data.size()) + " bytes, expected " +
                        std::to_string(expected));
    }
    return data;
}

void publish(const PublishArgs& args) {
    Participant dp(args.domain);
    fdds::DataWriterQos qos = fdds::DATAWRITER_QOS_DEFAULT;
    qos.reliability().kind = fdds::BEST_EFFORT_RELIABILITY_QOS;
    qos.durability().kind = fdds::VOLATILE_DURABILITY_QOS;
    qos.history().kind = fdds::KEEP_LAST_HISTORY_QOS;
    qos.history().depth = 5;
    std::vector<fdds::DataWriter*> writers;
    std::string topics;
    for (const Camera& cam : args.cameras) {
        fdds::DataWriter* w = dp.publisher()->create_datawriter(
            dp.topic(dds_topic(cam.topic), fdds::TypeSupport(new Image_PubSubType())), qos);
        if (w == nullptr) {
            throw PeerError("cannot create a writer for " + cam.topic);
        }
        writers.push_back(w);
        topics += (topics.empty() ? "" : ", ") + cam.topic;
    }
    wait_until(
        [&] {
            return std::all_of(writers.begin(), writers.end(),
                               [](fdds::DataWriter* w) { return matched(w) > 0; });
        },
        args.timeout_s, "readers of " + topics);
    say("ready " + dp.transports());

    const std::size_t bytes = static_cast<std::size_t>(args.width) * args.height * 3;
    std::string line;
    while (std::getline(std::cin, line)) {
        std::istringstream words(line);
        std::string command;
        if (!(words >> command)) {
            continue;
        }
        if (command == "quit") {
            return;
        }
        std::string k;
        std::uint64_t stamp = 0;
        std::vector<std::string> files;
        std::string file;
        if (command == "publish" && (words >> k >> stamp)) {
            while (words >> file) {
                files.push_back(file);
            }
        }
        if (command != "publish" || files.size() != args.cameras.size()) {
            throw PeerError("unknown command '" + line + "' (expected 'publish K STAMP_NS' and " +
                            std::to_string(args.cameras.size()) + " files, or 'quit')");
        }
        for (std::size_t i = 0; i < writers.size(); ++i) {
            Image_ msg;
            msg.header().stamp().sec(static_cast<std::int32_t>(stamp / kNanos));
            msg.header().stamp().nanosec(static_cast<std::uint32_t>(stamp % kNanos));
            msg.header().frame_id(args.cameras[i].frame_id);
            msg.height(args.height);
            msg.width(args.width);
            msg.encoding("rgb8");
            msg.is_bigendian(0);
            msg.step(args.width * 3);
            msg.data(read_file(files[i], bytes));
            if (!writers[i]->write(&msg)) {
                throw PeerError("writing to " + args.cameras[i].topic + " failed");
            }
        }
        say("published " + k + " " + std::to_string(stamp));
    }
}

double number(const std::string& flag, const std::string& text) {
    try {
        std::size_t used = 0;
        const double x = std::stod(text, &used);
        if (used == text.size() && std::isfinite(x)) {
            return x;
        }
    } catch (const std::exception&) {
    }
    throw UsageError(flag + ": '" + text + "' is not a number");
}

std::uint32_t count(const std::string& flag, const std::string& text) {
    const double x = number(flag, text);
    if (x < 1 || x > 1e6 || x != std::floor(x)) {
        throw UsageError(flag + ": '" + text + "' is not a count in 1..1000000");
    }
    return static_cast<std::uint32_t>(x);
}

int domain(const std::string& text) {
    const double x = number("--domain", text);
    if (x < 0 || x > 232 || x != std::floor(x)) {
        throw UsageError("--domain: '" + text + "' is not a domain id in 0..232");
    }
    return static_cast<int>(x);
}

const char* kUsage =
    "usage: fastdds_peer subscribe --domain D [--depth-topic T] [--points-topic T] "
    "[--max-depth-m M] [--timeout-s S]\n"
    "       fastdds_peer publish --domain D --width W --height H --camera TOPIC FRAME_ID "
    "[--camera ...] [--timeout-s S]\n";

}  // namespace

int main(int argc, char** argv) {
    std::vector<std::string> a(argv + 1, argv + argc);
    const std::string mode = a.empty() ? "" : a[0];
    try {
        auto value = [&](std::size_t& i) -> const std::string& {
            if (i + 1 >= a.size()) {
                throw UsageError(a[i] + " needs a value");
            }
            return a[++i];
        };
        if (mode == "subscribe") {
            SubscribeArgs args;
            for (std::size_t i = 1; i < a.size(); ++i) {
                if (a[i] == "--domain") {
                    args.domain = domain(value(i));
                } else if (a[i] == "--depth-topic") {
                    args.depth_topic = value(i);
                } else if (a[i] == "--points-topic") {
                    args.points_topic = value(i);
                } else if (a[i] == "--max-depth-m") {
                    args.max_depth_m = number(a[i], value(i));
                } else if (a[i] == "--timeout-s") {
                    args.timeout_s = number(a[i], value(i));
                } else {
                    throw UsageError("unknown argument '" + a[i] + "'");
                }
            }
            if (args.domain < 0) {
                throw UsageError("--domain is required");
            }
            subscribe(args);
        } else if (mode == "publish") {
            PublishArgs args;
            for (std::size_t i = 1; i < a.size(); ++i) {
                if (a[i] == "--domain") {
                    args.domain = domain(value(i));
                } else if (a[i] == "--width") {
                    args.width = count(a[i], value(i));
                } else if (a[i] == "--height") {
                    args.height = count(a[i], value(i));
                } else if (a[i] == "--camera") {
                    Camera cam;
                    cam.topic = value(i);
                    cam.frame_id = value(i);
                    args.cameras.push_back(cam);
                } else if (a[i] == "--timeout-s") {
                    args.timeout_s = number(a[i], value(i));
                } else {
                    throw UsageError("unknown argument '" + a[i] + "'");
                }
            }
            if (args.domain < 0 || args.width == 0 || args.height == 0 || args.cameras.empty()) {
                throw UsageError("--domain, --width, --height and --camera are required");
            }
            publish(args);
        } else {
            throw UsageError("the first argument must be 'subscribe' or 'publish'");
        }
    } catch (const UsageError& e) {
        std::cerr << "fastdds_peer: " << e.what() << "\n" << kUsage;
        return 2;
    } catch (const std::exception& e) {
        std::cerr << "fastdds_peer " << mode << ": " << e.what() << std::endl;
        return 1;
    }
    return 0;
}
