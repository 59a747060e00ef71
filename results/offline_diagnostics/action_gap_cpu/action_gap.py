import numpy as np, jax, jax.numpy as jnp
from offline import collect
from envs.evaluate import hand_designed_policy
env=collect.make_env("three_link/env3"); ex=hand_designed_policy(env); g=0.99
T0=int(__import__("sys").argv[1]); H=400
def branch(key):
    s=env.reset(key)
    s=jax.lax.fori_loop(0,T0,lambda i,s: env.step(s,jnp.clip(ex(s),-1,1)),s)
    a_ex=jnp.clip(ex(s),-1,1)
    def ret(a0):
        s1=env.step(s,a0)
        def body(c,t):
            st,acc=c
            n=env.step(st,jnp.clip(ex(st),-1,1))
            n=jax.tree.map(lambda x,y: jnp.where(st.done>0,y,x),n,st)
            return (n, acc + jnp.where(st.done>0,0.0,n.reward)*g**(t+1)),None
        (_,acc),_=jax.lax.scan(body,(s1,s1.reward),jnp.arange(H))
        return acc
    return jnp.stack([ret(a_ex), ret(-a_ex), ret(jnp.zeros_like(a_ex)), ret(jnp.ones_like(a_ex)), ret(-jnp.ones_like(a_ex))])
q=np.asarray(jax.jit(jax.vmap(branch))(jax.random.split(jax.random.PRNGKey(3),64)))
print("T0",T0,"Q(expert) mean %.3f"%q[:,0].mean(), "|Q(ex)-Q(-ex)| mean %.4f"%np.abs(q[:,0]-q[:,1]).mean(), "|Q(ex)-Q(0)| %.4f"%np.abs(q[:,0]-q[:,2]).mean(), "|Q(+1)-Q(-1)| %.4f"%np.abs(q[:,3]-q[:,4]).mean(), "max over actions - min: %.4f"%(q.max(1)-q.min(1)).mean())
