"""The physics as components: mechanical, pneumatic and the APS/myofibril assembly."""
