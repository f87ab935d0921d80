/* A command-line harness around libnifalcon's own kinematics, packet and firmware-upload code (our code: it
 * only calls libnifalcon; libnifalcon's sources are not in this repository).
 *
 * It is linked, outside this repository, with libnifalcon's FalconKinematicStamper, FalconFirmwareNovintSDK
 * and FalconFirmware (BSD) and the small GMTL stand-in beside it (falcon/gmtl/gmtl.h, written for this
 * harness), and driven by ../falcon_vectors.py, which records its answers as the contract test's vectors
 * (../vectors/falcon_libnifalcon.json; ../vectors/README.md says with which libnifalcon commit).
 * One command per line on stdin, one answer per line on stdout:
 *   ik X Y Z               -> theta1[3] theta2[3] theta3[3]           (rad; IK of FalconKinematicStamper)
 *   jac X Y Z              -> 9 numbers, row-major                     (jacobian(IK(p)))
 *   forces X Y Z FX FY FZ  -> 3 ints                                   (getForces)
 *   theta N                -> degrees                                  (FalconKinematic::getTheta)
 *   pos E0 E1 E2           -> X Y Z                                    (getPosition: FK from its last guess)
 *   pack C0 C1 C2 LEDS HOM -> 32 hex digits                            (FalconFirmwareNovintSDK::runIOLoop's write)
 *   unpack HEX32           -> E0 E1 E2 HOMING GRIP OK                  (runIOLoop's read of one device packet)
 *   load N                 -> then "W <hex>" lines out, "R <hex>" lines in, per block, and "LOAD <0|1> <code>"
 *                             (FalconFirmware::loadFirmware on an N-byte image read as one hex line first)
 */
#include <array>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "falcon/firmware/FalconFirmwareNovintSDK.h"
#include "falcon/kinematic/FalconKinematicStamper.h"

using namespace libnifalcon;

static std::string hex(const uint8_t *b, unsigned n) {
    static const char *d = "0123456789abcdef";
    std::string s;
    for (unsigned i = 0; i < n; ++i) { s += d[b[i] >> 4]; s += d[b[i] & 15]; }
    return s;
}

static std::vector<uint8_t> unhex(const std::string &s) {
    std::vector<uint8_t> out;
    for (size_t i = 0; i + 1 < s.size(); i += 2) out.push_back((uint8_t)std::stoi(s.substr(i, 2), nullptr, 16));
    return out;
}

/* A FalconComm that records what the firmware code writes and hands it the bytes the test gives. */
class TestComm : public FalconComm {
  public:
    std::vector<uint8_t> written, to_read;
    bool bridge = false; /* load: blocking calls go out to the test over stdout/stdin */
    TestComm() { m_isCommOpen = true; }
    bool getDeviceCount(unsigned int &count) override { count = 1; return true; }
    bool open(unsigned int) override { return true; }
    bool close() override { return true; }
    void poll() override { m_hasBytesAvailable = !to_read.empty(); m_bytesAvailable = to_read.size(); }
    bool read(uint8_t *str, unsigned int size) override {
        unsigned n = size < to_read.size() ? size : to_read.size();
        memcpy(str, to_read.data(), n);
        to_read.erase(to_read.begin(), to_read.begin() + n);
        m_lastBytesRead = n;
        return true;
    }
    bool write(uint8_t *str, unsigned int size) override {
        written.assign(str, str + size);
        m_lastBytesWritten = size;
        return true;
    }
    bool readBlocking(uint8_t *str, unsigned int size) override {
        std::string line;
        if (!std::getline(std::cin, line) || line.size() < 2 || line[0] != 'R') { m_lastBytesRead = 0; return false; }
        std::vector<uint8_t> b = unhex(line.substr(2));
        unsigned n = size < b.size() ? size : b.size();
        memcpy(str, b.data(), n);
        m_lastBytesRead = n;
        return n > 0;
    }
    bool writeBlocking(uint8_t *str, unsigned int size) override {
        std::cout << "W " << hex(str, size) << std::endl;
        m_lastBytesWritten = size;
        return true;
    }
    bool setFirmwareMode() override { return true; } /* the FTDI set-up: FalconCommLibUSB, not compiled here */
    bool setNormalMode() override { return true; }
};

int main() {
    std::cout.precision(17);
    FalconKinematicStamper kin(false);
    std::string line;
    while (std::getline(std::cin, line)) {
        std::istringstream in(line);
        std::string cmd;
        in >> cmd;
        if (cmd == "ik" || cmd == "jac") {
            double x, y, z;
            in >> x >> y >> z;
            StamperKinematicImpl::Angle a;
            kin.IK(a, gmtl::Vec3d(x, y, z));
            if (cmd == "ik") {
                for (int i = 0; i < 3; ++i) std::cout << a.theta1[i] << " ";
                for (int i = 0; i < 3; ++i) std::cout << a.theta2[i] << " ";
                for (int i = 0; i < 3; ++i) std::cout << a.theta3[i] << (i < 2 ? " " : "\n");
            } else {
                gmtl::Matrix33d J = kin.jacobian(a);
                for (int r = 0; r < 3; ++r)
                    for (int c = 0; c < 3; ++c) std::cout << J(r, c) << (r == 2 && c == 2 ? "\n" : " ");
            }
        } else if (cmd == "forces") {
            std::array<double, 3> p, f;
            std::array<int, 3> e;
            in >> p[0] >> p[1] >> p[2] >> f[0] >> f[1] >> f[2];
            kin.getForces(p, f, e);
            std::cout << e[0] << " " << e[1] << " " << e[2] << "\n";
        } else if (cmd == "theta") {
            int n;
            in >> n;
            std::cout << kin.getTheta(n) << "\n";
        } else if (cmd == "pos") {
            std::array<int, 3> e;
            std::array<double, 3> p;
            in >> e[0] >> e[1] >> e[2];
            kin.getPosition(e, p);
            std::cout << p[0] << " " << p[1] << " " << p[2] << "\n";
        } else if (cmd == "pack" || cmd == "unpack") {
            auto comm = std::make_shared<TestComm>();
            FalconFirmwareNovintSDK fw;
            fw.setFalconComm(comm);
            if (cmd == "pack") {
                std::array<int, 3> c;
                unsigned leds;
                int hom;
                in >> c[0] >> c[1] >> c[2] >> leds >> hom;
                fw.setForces(c);
                fw.setLEDStatus(leds);
                fw.setHomingMode(hom != 0);
                fw.runIOLoop();
                std::cout << hex(comm->written.data(), comm->written.size()) << "\n";
            } else {
                std::string h;
                in >> h;
                fw.runIOLoop(); /* first loop writes (nothing read yet) */
                comm->to_read = unhex(h);
                bool ok = fw.runIOLoop();
                std::array<int, 3> e = fw.getEncoderValues();
                std::cout << e[0] << " " << e[1] << " " << e[2] << " " << fw.getHomingModeStatus() << " "
                          << (int)fw.getGripInfo()[0] << " " << ok << "\n";
            }
        } else if (cmd == "load") {
            unsigned n;
            in >> n;
            std::string h;
            std::getline(std::cin, h);
            std::vector<uint8_t> image = unhex(h);
            auto comm = std::make_shared<TestComm>();
            FalconFirmwareNovintSDK fw;
            fw.setFalconComm(comm);
            bool ok = fw.loadFirmware(false, n, image.data());
            std::cout << "LOAD " << ok << " " << fw.getErrorCode() << std::endl;
        }
        std::cout.flush();
    }
    return 0;
}
