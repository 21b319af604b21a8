#include <pcl/impl/instantiate.hpp>
#include <pcl/rast/point_types.h>
#include <pcl/registration/impl/raster_orb_registration.hpp>

namespace pcl {
namespace rast {

bool
RasterORBRegistrationParams::isValid(std::string* why) const
{
  std::string reason;
  if (remove_ground && !ground.isValid(&reason))
    reason = "ground." + reason;
  else if (!raster.isValid(&reason))
    reason = "raster." + reason;
  else if (!orb.isValid(&reason))
    reason = "orb." + reason;
  else if (!registration.isValid(&reason))
    reason = "registration." + reason;
  if (why)
    *why = reason;
  return reason.empty();
}

} // namespace rast
} // namespace pcl

PCL_INSTANTIATE(RasterORBRegistration, PCL_RAST_XYZ_POINT_TYPES)
